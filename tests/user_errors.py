"""A command's user error as the tests expect it: exit code 2, one line without a traceback naming
what is wrong, and no output file written (shared by the export and show hardening tests)."""


def assert_user_error(code, err, out, *needles):
    assert code == 2, (code, err)
    assert len(err) == 1 and "Traceback" not in err[0], err
    for n in needles:
        assert n in err[0], (n, err)
    assert not out.exists()
