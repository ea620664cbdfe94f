"""The API reference from the docstrings: `make docs` (or `python docs/api_reference.py OUT_DIR`)
writes OUT_DIR/index.html with pdoc, the Python API (`surestep_ocp`'s exports, documented in full on
its page) and the modules behind it.

The package imports its exports on first use (`surestep_ocp.__getattr__`); they are resolved here
first so that pdoc finds them in the package's namespace.
"""

from __future__ import annotations

import sys
from pathlib import Path

# the package page (every export in full), then the modules a user of the API reads further in
MODULES = ["surestep_ocp", "surestep_ocp.api", "surestep_ocp.errors", "surestep_ocp.problem.spec",
           "surestep_ocp.problem.load", "surestep_ocp.output.solution",
           "surestep_ocp.output.export", "surestep_ocp.methods.planner",
           "surestep_ocp.evaluation.tracker", "surestep_ocp.ocp.codegen"]


def build(out: Path) -> Path:
    import pdoc

    import surestep_ocp

    for name in surestep_ocp.__all__:  # the lazy exports, resolved
        getattr(surestep_ocp, name)
    pdoc.render.configure(docformat="google",
                          footer_text=f"surestep_ocp {surestep_ocp.__version__}",
                          search=True, show_source=True)
    pdoc.pdoc(*MODULES, output_directory=out)
    return out / "index.html"


if __name__ == "__main__":
    target = Path(sys.argv[1] if len(sys.argv) > 1 else "docs/api")
    print(f"wrote {build(target)}")
