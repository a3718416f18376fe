#!/usr/bin/env bash
# The README's main job from an empty cache, for two or more revisions, one after the other in the
# same hour (this machine's speed varies about 2x between hours: compare revisions within one run).
#
#   bash benchmarks/main_job_ab.sh OUT.json REV [REV ...]     # e.g. 5c72ce9 HEAD
#
# Each revision is cloned fresh into /tmp/main-job-<rev> (no .cache: data, models and solver caches
# start empty) and runs the README's command, `pip install -e . && python -m active.run`, timed.
# Writes OUT.json: per revision the wall time, the seconds until the experiment's first iteration,
# and the run's results.csv phase totals per method. PARSE_ONLY=1 re-reads existing clones.
# The clones' `pip install -e .` repoints the editable install: this script points it back at the
# repository it was started from.
set -euo pipefail
out=$1; shift
repo=$(git -C "$(dirname "$0")/.." rev-parse --show-toplevel)
restore() { pip install -q -e "$repo" --no-deps --no-build-isolation && rm -rf "$repo/build"; }
trap restore EXIT  # whatever happens, the editable install points back at this repository
for rev in "$@"; do
  d=/tmp/main-job-$rev
  if [ -z "${PARSE_ONLY:-}" ]; then
    rm -rf "$d" && git clone -q "$repo" "$d" && git -C "$d" checkout -q "$rev"
    echo "== $rev ($(git -C "$d" rev-parse --short HEAD)) start $(date +%T)"
    ( cd "$d" && /usr/bin/time -f "wall %e s" bash -c 'pip install -q -e . 2>/dev/null; python -m active.run' ) \
      > "$d.log" 2>&1 || echo "== $rev FAILED (see $d.log)"
    echo "== $rev end $(date +%T): $(tail -1 "$d.log")"
  fi
done
python - "$out" "$@" <<'PY'
import csv, json, re, subprocess, sys
out, revs = sys.argv[1], sys.argv[2:]
res = {}
for rev in revs:
    d = f"/tmp/main-job-{rev}"
    log = open(f"{d}.log").read().replace("\r", "\n")
    walls = re.findall(r"^wall ([0-9.]+) s", log, re.M)
    if not walls or "Command exited with non-zero status" in log:
        res[rev] = {"failed": True, "log": f"{d}.log"}
        print(f"{rev:>10}  FAILED (see {d}.log)")
        continue
    wall = float(walls[-1])
    commit = subprocess.run(["git", "-C", d, "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    methods = {}
    for m in ("active_balanced", "random_plan"):
        rows = list(csv.DictReader(open(f"{d}/outputs/quick/all/seed0/{m}/results.csv")))
        methods[m] = {k: round(sum(float(r[k] or 0) for r in rows), 1)
                      for k in ("plan_seconds", "sim_seconds", "fit_seconds", "test_seconds", "iteration_seconds")}
        methods[m]["test_success"] = [float(r["test_success"]) for r in rows]
    trained = len(re.findall(r"dynamics.train\]\[INFO\] - wrote .*model.pt", log))
    shipped = len(re.findall(r"using the shipped dynamics model", log))
    res[rev] = {"commit": commit, "wall_s": wall, "models_trained": trained, "models_shipped": shipped,
                "methods": methods}
    print(f"{rev:>10}  wall {wall:7.1f} s  models trained {trained}, shipped {shipped}  "
          + "  ".join(f"{m}: plan {v['plan_seconds']} s, sim {v['sim_seconds']} s, test {v['test_seconds']} s"
                      for m, v in methods.items()))
if len(revs) > 1 and all("wall_s" in res[r] for r in (revs[0], revs[-1])):
    print(f"ratio {revs[0]} / {revs[-1]}: {res[revs[0]]['wall_s'] / res[revs[-1]]['wall_s']:.2f}x")
json.dump(res, open(out, "w"), indent=1)
PY
