"""A fresh fuzz, independent of tests/test_fuzz_problem.py (another generator, other mutations):
`surestep validate` in-process on N mutated shipped problems, then `surestep solve` on a sample of
the accepted ones (tracebacks, timeouts over 120 s, NaN in outputs, multi-line errors). Usage:
python benchmarks/fuzz_fresh.py SEED N SOLVES (issue 17: seed 4242, 1500, 25)."""
import harness as h  # first: one BLAS thread
import copy, random, subprocess, sys, time, glob, yaml, os
REPO = h.ROOT
import tempfile
WORK = tempfile.mkdtemp(prefix="surestep-fuzz-")
load_problem, build_setup, ProblemError, SurestepError = (
    h.load_problem, h.setup, h.ProblemError, h.SurestepError)
rng = random.Random(int(sys.argv[1]) if len(sys.argv) > 1 else 4242)
files = sorted(glob.glob(str(REPO / "problems" / "*.yaml")))
trees = {f: yaml.safe_load(open(f)) for f in files}
def leaves(node, pre=()):
    out = []
    it = (node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list)
          else [])
    for k, v in it:
        out.append((*pre, k)); out += leaves(v, (*pre, k))
    return out
def get(t, p):
    for k in p: t = t[k]
    return t
stats = {"accepted": 0, "rejected": 0, "other": 0, "multiline": 0, "long": 0}
bad = []
accepted = []
N = int(sys.argv[2]) if len(sys.argv) > 2 else 1500
t0 = time.time()
for i in range(N):
    f = rng.choice(files); tree = copy.deepcopy(trees[f])
    ps = leaves(tree); p = rng.choice(ps); parent = get(tree, p[:-1]); v = get(tree, p)
    op = rng.choice(["mul", "swap", "neg", "str", "dup", "big", "tiny", "none", "nest"])
    if op == "mul" and isinstance(v, (int, float)) and not isinstance(v, bool):
        parent[p[-1]] = v * 10 ** rng.uniform(-15, 15)
    elif op == "swap":
        q = rng.choice(ps)
        try: parent[p[-1]] = copy.deepcopy(get(tree, q))
        except Exception: pass
    elif op == "neg" and isinstance(v, (int, float)) and not isinstance(v, bool):
        parent[p[-1]] = -v
    elif op == "str": parent[p[-1]] = rng.choice(["\t", "nan", "Infinity", "0x10", "1_000", "~",
                                                  "yes", "é" * 3])
    elif op == "dup" and isinstance(v, list): parent[p[-1]] = v + v
    elif op == "big": parent[p[-1]] = rng.choice([2**1000, 1e300, -2**64, 10**18])
    elif op == "tiny": parent[p[-1]] = rng.choice([1e-320, -0.0, 1e-200, 2.2e-308])
    elif op == "none": parent[p[-1]] = None
    elif op == "nest": parent[p[-1]] = [v]
    path = f"{WORK}/case{i}.yaml"
    with open(path, "w") as fh: yaml.safe_dump(tree, fh)
    try:
        build_setup(load_problem(path)); stats["accepted"] += 1; accepted.append(path)
    except ProblemError as e:
        s = str(e); stats["rejected"] += 1
        if "\n" in s: stats["multiline"] += 1; bad.append(("multiline", path, s[:200]))
        if len(s) > 1000: stats["long"] += 1
    except Exception as e:
        stats["other"] += 1; bad.append((type(e).__name__, path, str(e)[:200]))
print("validate:", stats, f"{time.time() - t0:.1f} s", flush=True)
for b in bad[:20]: print("BAD", b)
# solve a sample of the accepted ones
rng.shuffle(accepted)
res = {"ok": 0, "solver_fail": 0, "user_error": 0, "other": 0, "timeout": 0, "nan": 0}
for path in accepted[: int(sys.argv[3]) if len(sys.argv) > 3 else 25]:
    out = path.replace(".yaml", ".json")
    try:
        pr = subprocess.run([sys.executable, "-m", "surestep_ocp.cli", "solve", path, "--output",
                             out], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        res["timeout"] += 1; print("TIMEOUT", path, flush=True); continue
    if "Traceback" in pr.stderr or pr.returncode not in (0, 1, 2):
        res["other"] += 1; print("CRASH", path, pr.returncode, pr.stderr[-300:], flush=True)
    elif pr.returncode == 0: res["ok"] += 1
    elif pr.returncode == 1: res["solver_fail"] += 1; print("FAIL1", path, pr.stderr.strip()[-200:])
    else: res["user_error"] += 1; print("ERR2", path, pr.stderr.strip()[-200:])
    if len(pr.stderr.strip().splitlines()) > 1 and pr.returncode != 0: print("MULTILINE", path,
                                                                              pr.stderr[-300:])
    if os.path.exists(out):
        txt = open(out).read()
        if "NaN" in txt or "Infinity" in txt: res["nan"] += 1; print("NAN", out)
print("solve:", res, flush=True)
