"""Combine the per-run JSONs of benchmarks/peers/genesis.sh into one result and print a table.

    python benchmarks/peers/combine_genesis.py --raw DIR --out benchmarks/results/peers_genesis.json

Per (dx, B): the best (highest particle-substeps/s) of the rounds of each solver, every round's
figure, the ratio ours / genesis, both front curves (from the best runs) and their mean relative
difference over T >= 0.8 (before that both fronts sit at Z ~ 1 and agree trivially), each solver's
mean relative error against Martin & Moyce (1952) with the max_low front (benchmarks/validate.py's
definition) and the load averages seen by every run.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import dambreak_common as C  # noqa: E402

T_MIN = 0.8


def load_mm() -> np.ndarray:
    for p in (
        C.REPO / "sim/data/martin_moyce_1952_surge_front.csv",
        C.REPO.parent / "shared/data/martin_moyce_1952_surge_front.csv",
    ):
        if p.exists():
            rows = [ln for ln in p.read_text().splitlines() if ln and ln[0].isdigit()]
            return np.array([[float(v) for v in r.split(",")] for r in rows])
    return np.zeros((0, 2))


def front_diff(fo: dict, fg: dict, key: str) -> tuple[float | None, int]:
    """Mean relative difference of the two front curves over T >= T_MIN, and how many samples."""
    To, Zo = np.asarray(fo["T"]), np.asarray(fo[key])
    Tg, Zg = np.asarray(fg["T"]), np.asarray(fg[key])
    n = min(len(To), len(Tg))
    if n == 0 or not np.allclose(To[:n], Tg[:n], atol=1e-6):
        return None, 0
    m = To[:n] >= T_MIN
    if not m.any():
        return None, 0
    return float(np.mean(np.abs(Zg[:n][m] - Zo[:n][m]) / Zo[:n][m])), int(m.sum())


def mm_error(front: dict, mm: np.ndarray) -> float | None:
    T, Z = np.asarray(front["T"]), np.asarray(front["Z_max_low"])
    m = (mm[:, 0] >= T_MIN) & (mm[:, 0] <= T.max() + 1e-9) if len(mm) else np.zeros(0, bool)
    if not m.any():
        return None
    Zi = np.interp(mm[m, 0], T, Z)
    return float(np.mean(np.abs(Zi - mm[m, 1]) / mm[m, 1]))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--raw", type=Path, required=True, help="folder of the per-run JSONs")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--loadavg-start", type=str, default="", help="load averages at the start of the whole run")
    ap.add_argument("--command", type=str, default="")
    ap.add_argument("--loadavg-end", type=str, default="", help="load averages at the end (default: now)")
    ap.add_argument("--note", type=str, default="", help="free text stored in the JSON")
    ap.add_argument("--runs-seconds", type=float, default=None, help="wall time of all the runs")
    args = ap.parse_args(argv)

    runs = defaultdict(lambda: defaultdict(list))
    for p in sorted(args.raw.glob("*.json")):
        r = json.loads(p.read_text())
        r["_file"] = p.name
        runs[(r["dx"], r["envs"])][r["solver"]].append(r)
    mm = load_mm()
    rows = []
    for (dx, B), by in sorted(runs.items(), key=lambda kv: (-kv[0][0], kv[0][1])):
        row = {"dx": dx, "envs": B}
        best = {}
        for s in ("ours", "genesis"):
            rs = by.get(s, [])
            if not rs:
                continue
            b = max(rs, key=lambda r: r["particle_substeps_per_s"])
            best[s] = b
            row[s] = {
                "particles": b["particles"],
                "particles_expected": b["particles_expected"],
                "dt": b["dt"],
                "substeps": b["substeps"],
                "seconds": b["seconds"],
                "particle_substeps_per_s": b["particle_substeps_per_s"],
                "rounds_particle_substeps_per_s": [r["particle_substeps_per_s"] for r in rs],
                "rounds_loadavg": [{"start": r["loadavg_start"], "end": r["loadavg_end"]} for r in rs],
                "setup_seconds": b.get("build_seconds", 0.0) + b.get("compile_seconds", 0.0),
                "threads": b["threads"],
                "arch": b["arch"],
                "nan": b.get("nan"),
                "unstable": b.get("unstable"),
                "front": b["front"],
                "martin_moyce_error_max_low": mm_error(b["front"], mm),
            }
            if s == "ours":
                row[s]["taichi_version"] = b["taichi_version"]
                row[s]["source"] = b.get("source")
                row[s]["config"] = b["config"]
                row[s]["model"] = b["model"]
            else:
                for k in (
                    "genesis_version",
                    "quadrants_version",
                    "torch_version",
                    "performance_mode",
                    "genesis_settings",
                    "model",
                ):
                    row[s][k] = b[k]
        if len(best) == 2:
            o, g = best["ours"], best["genesis"]
            row["ratio_ours_over_genesis"] = o["particle_substeps_per_s"] / g["particle_substeps_per_s"]
            row["particle_count_difference"] = (g["particles"] - o["particles"]) / o["particles"]
            row["front_mean_rel_diff_p99"], nf = front_diff(o["front"], g["front"], "Z_p99")
            row["front_mean_rel_diff_max_low"], _ = front_diff(o["front"], g["front"], "Z_max_low")
            row["front_samples_compared"] = nf
            row["front_T_end"] = min(o["front"]["T"][-1], g["front"]["T"][-1])
        row["scene"] = next(iter(best.values()))["scene"]
        rows.append(row)

    all_runs = [r for by in runs.values() for rs in by.values() for r in rs]
    first = min(all_runs, key=lambda r: r["_file"]) if all_runs else {}
    res = {
        "benchmark": "3D dam break (Martin & Moyce n^2 = 2 column across the tank), ours (sim.engine.mpm.MPMSolver) vs "
        "Genesis MPM Liquid; particle-substeps/s = B * particles * substeps / timed seconds; best of "
        "the rounds, solvers run alternately (ours, genesis, ours, genesis) in separate processes",
        "command": args.command,
        "front_metrics": "Z = front / a against T = t sqrt(2 g / a), a = 0.1 m; p99: 99th percentile of particle x; "
        "max_low: furthest particle within 0.1 a of the floor (benchmarks/validate.py); differences are "
        f"mean |Z_genesis - Z_ours| / Z_ours over the samples with T >= {T_MIN}",
        "loadavg_start": [float(v) for v in args.loadavg_start.split()] if args.loadavg_start else None,
        "loadavg_end": (
            [float(v) for v in args.loadavg_end.split()] if args.loadavg_end else list(__import__("os").getloadavg())
        ),
        "runs_wall_seconds": args.runs_seconds,
        "note": args.note or None,
        "raw_runs": str(args.raw),
        "machine": first.get("machine"),
        "taichi_version_ours": next((r["taichi_version"] for r in all_runs if r["solver"] == "ours"), None),
        "genesis_version": next((r["genesis_version"] for r in all_runs if r["solver"] == "genesis"), None),
        "quadrants_version_genesis": next((r["quadrants_version"] for r in all_runs if r["solver"] == "genesis"), None),
        "rows": rows,
    }
    C.write_json(args.out, res)

    hdr = (
        f"{'dx mm':>6} {'B':>3} {'particles ours/gen':>19} {'dt':>7} {'substeps':>8} {'ours p-sub/s':>12} "
        f"{'genesis p-sub/s':>15} {'ratio':>6} {'front p99':>9} {'front low':>9} {'to T':>5} {'M&M ours/gen':>13}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        o, g = r.get("ours", {}), r.get("genesis", {})

        def f(v, fmt):
            return format(v, fmt) if isinstance(v, (int, float)) else "-"

        mmo, mmg = o.get("martin_moyce_error_max_low"), g.get("martin_moyce_error_max_low")
        print(
            f"{r['dx'] * 1000:6.1f} {r['envs']:3d} {f(o.get('particles'), 'd'):>9}/{f(g.get('particles'), 'd'):<9} "
            f"{f(o.get('dt', g.get('dt')), '.0e'):>7} {f(o.get('substeps', g.get('substeps')), 'd'):>8} "
            f"{f(o.get('particle_substeps_per_s'), '.3g'):>12} {f(g.get('particle_substeps_per_s'), '.3g'):>15} "
            f"{f(r.get('ratio_ours_over_genesis'), '.2f'):>6} "
            f"{f(100 * r['front_mean_rel_diff_p99'] if r.get('front_mean_rel_diff_p99') is not None else None, '.1f'):>8}% "  # noqa: E501 (a table row's format reads best on one line)
            f"{f(100 * r['front_mean_rel_diff_max_low'] if r.get('front_mean_rel_diff_max_low') is not None else None, '.1f'):>8}% "  # noqa: E501 (a table row's format reads best on one line)
            f"{f(r.get('front_T_end'), '.1f'):>5} "
            f"{f(100 * mmo if mmo is not None else None, '.1f'):>6}/{f(100 * mmg if mmg is not None else None, '.1f'):<5}%"  # noqa: E501 (a table row's format reads best on one line)
        )
    print(f"load average: start {res['loadavg_start']}  end {[round(v, 2) for v in res['loadavg_end']]}")
    print(f"wrote {args.out}")
    return res


if __name__ == "__main__":
    main()
