"""`surestep cache [--info | --clear | --prune [--max-mb N]]`: the compile cache of the OCP's
derivatives.

Where it is and how it is bounded: `ocp/codegen.py` (docs/cli.md, "The compile cache").
"""

from __future__ import annotations

import time

from .errors import SurestepError
from .ocp import codegen


def _mb(n: int) -> str:
    return f"{n / 1e6:.1f} MB"


def info_text() -> str:
    folder = codegen.cache_dir()
    libs = codegen.entries(folder)
    bound = codegen.max_bytes()
    env = __import__("os").environ
    where = ("$SURESTEP_CACHE" if env.get("SURESTEP_CACHE") else
             "$XDG_CACHE_HOME/surestep_ocp" if env.get("XDG_CACHE_HOME", "").startswith("/")
             else "the default, ~/.cache/surestep_ocp")
    rate, basis = codegen._rate(folder)
    orphans, live = codegen.partial_writes(folder)
    lines = [
        f"folder      {folder} ({where}){'' if folder.is_dir() else ' - not created yet'}",
        f"libraries   {len(libs)} ({_mb(sum(e.size for e in libs))} with their checksums; "
        f"{_mb(codegen.total_bytes(folder))} in all)",
        f"partial     {len(orphans)} orphaned partial writes (a compile killed midway; removed by "
        f"--prune and --clear), {len(live)} of a compile under way",
        "bound       " + ("none ($SURESTEP_CACHE_MAX_MB=0)" if bound is None else
                          f"{_mb(bound)}: the least recently used libraries are removed after a "
                          f"compile ($SURESTEP_CACHE_MAX_MB, default {codegen.DEFAULT_MAX_MB})"),
        f"estimate    {basis} (the compile notes' time estimate)",
    ]
    if libs:
        def when(lib) -> str:
            return time.strftime('%Y-%m-%d %H:%M', time.localtime(lib.last_use))

        lines.append(f"last used   {when(libs[-1])} (least recently: {when(libs[0])})")
    lines.append("clear it    surestep cache --clear (it is rebuilt as needed; the first solve of "
                 "each problem structure and horizon compiles again)")
    return "\n".join(lines)


def cmd_cache(args) -> int:
    folder = codegen.cache_dir()
    if args.clear:
        freed = codegen.clear(folder)
        print(f"cleared     {folder} ({_mb(freed)} freed)")
        return 0
    if args.prune:
        limit = (codegen.max_bytes() if args.max_mb is None
                 else codegen.megabytes(args.max_mb, "--max-mb"))
        removed = codegen.prune(limit, folder)
        left = codegen.entries(folder)
        print(f"pruned      {len(removed)} libraries ({_mb(sum(e.size for e in removed))}) from "
              f"{folder}; {len(left)} left ({_mb(sum(e.size for e in left))}, bound "
              f"{'none' if limit is None else _mb(limit)})")
        return 0
    if args.max_mb is not None:
        raise SurestepError("--max-mb applies to --prune only")
    print(info_text())
    return 0


def register(sub) -> None:
    """Add `surestep cache` to the CLI's subcommands."""
    c = sub.add_parser(
        "cache", help="where the compiled derivatives are cached, their size; clear or prune them",
        description="The OCP's derivatives compiled to C are cached by content in $SURESTEP_CACHE, "
                    "else $XDG_CACHE_HOME/surestep_ocp, else ~/.cache/surestep_ocp; after a "
                    "compile the least recently used libraries are removed while the cache holds "
                    "more than $SURESTEP_CACHE_MAX_MB megabytes (0: unbounded).")
    what = c.add_mutually_exclusive_group()
    what.add_argument("--info", action="store_true",
                      help="print the folder, its size, its bound and the compile estimate's rate "
                           "(what `surestep cache` alone does)")
    what.add_argument("--clear", action="store_true",
                      help="remove every compiled library from the cache")
    what.add_argument("--prune", action="store_true",
                      help="remove the least recently used libraries until the cache holds at most "
                           "--max-mb")
    c.add_argument("--max-mb", metavar="MB",
                   help="the size to prune to, in megabytes (with --prune; default: "
                        "$SURESTEP_CACHE_MAX_MB, else the default bound)")
    c.set_defaults(func=cmd_cache)
