"""python benchmarks/scratch_s38/rounds.py NAME=GLOB ... : mean test success per round over the seeds of each
results.csv glob, e.g. admission='S38P/seed*/active_admission/results.csv' random_plan='results/paper/run/seed*/random_plan/results.csv'
(session 38's per-round figures and the rounds 1-10 / 11-20 means)."""
import csv, glob, sys
for arg in sys.argv[1:]:
    name, pattern = arg.split("=", 1)
    per = {}
    for f in glob.glob(pattern):
        for r in csv.DictReader(open(f)):
            per.setdefault(int(r["iteration"]), []).append(float(r["test_success"]))
    means = [sum(v) / len(v) for _, v in sorted(per.items())]
    print(name, " ".join(f"{x:.2f}" for x in means), f"| rounds 1-10 {sum(means[:10]) / len(means[:10]):.3f}",
          f"11-20 {sum(means[10:]) / max(len(means[10:]), 1):.3f}" if len(means) > 10 else "")
