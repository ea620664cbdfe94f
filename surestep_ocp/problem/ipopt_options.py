"""The IPOPT option check: whether IPOPT accepts a problem's raw `solver.options` (names and value
types).

IPOPT itself is asked (a one-variable NLP built with the options), so the check knows every option
of the installed IPOPT; its reason for a refusal is caught from stdout and said in one line.
"""

from __future__ import annotations

import io
import os
import re
import sys
import tempfile

import casadi as ca

from ..errors import shown


def check_ipopt_options(options: dict) -> str | None:
    """None if IPOPT accepts `options` (names and value types), else a one-line reason."""
    if not options:
        return None
    x = ca.MX.sym("x")
    sys.stdout.flush()
    saved, python_out, caught = os.dup(1), sys.stdout, io.StringIO()
    # IPOPT says why a setting is invalid on stdout: CasADi's (Python's sys.stdout) or the C one
    with tempfile.TemporaryFile() as printed:
        os.dup2(printed.fileno(), 1)
        sys.stdout = caught
        try:
            ca.nlpsol("check_options", "ipopt", {"x": x, "f": x**2},
                      {"ipopt": dict(options, print_level=0, sb="yes"), "print_time": False})
            return None
        except RuntimeError as exc:
            error = str(exc)
        finally:
            sys.stdout = python_out
            os.dup2(saved, 1)
            os.close(saved)
        printed.seek(0)
        said = caught.getvalue()[:4000] + "\n" + printed.read(4000).decode("utf-8", "replace")
    reason = next((ln for ln in said.splitlines() if "valid setting" in ln or "Option" in ln),
                  "") or error
    reason = re.sub(r"^.*?\.cpp:\d+:\s*", "",
                    reason.strip().splitlines()[-1] if reason.strip() else error)
    return f"IPOPT refused them: {shown(reason.strip(), 200)}"
