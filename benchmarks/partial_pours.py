"""Where the labels of the partial first pours come from:
``python -m benchmarks.partial_pours --sets S/ceiling_train_seed0.npz ...``.

Why: the MDE refuses the pours that every mid-range goal needs (a full cup that pours part of its water into
the target cup), because their labels in the target world scatter (BENCHMARKS.md, "Admission"). This takes
each such pour of saved ceiling sets (``active.ladder --rungs ceiling --ceiling-seeds ...``) apart by executing
it again:

- ``history``: its exact action prefix from its problem's start, in its recorded env slot (must reproduce the
  recorded outcome bit for bit on the CPU that made the set) and in ``--slots - 1`` other slots (particle
  sampling);
- ``rest``: the pour alone from rest at the recorded pre-pour pose (a zero move, i.e. one settle, then the
  pour), in the same slots: history against no history;
- ``source``: the same from rest in the source world (no plant): the model's own error where it was trained;
- ``jitter``: from rest in the target world under ``--jitters`` fresh plant-pose jitters (and none), recorded
  slot: whether the plant's unobserved pose decides the outcome.

``--mde`` files: each saved MDE's mean, std and noise std at the pours that are good under every jitter.
Prints a table, writes every pour's outcomes as JSON (``--out``).
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from benchmarks._cli import report

EXTRA_SLOTS = (101, 202, 303, 404, 505, 606, 707)


def set_seed(path: Path, given: int | None) -> int:
    """The ladder seed a ceiling set was made with (its file name ``ceiling_train_seed<k>.npz``, or ``given``)."""
    if given is not None:
        return given
    m = re.search(r"seed(\d+)", path.name)
    if not m:
        raise ValueError(f"--sets {path}: no seed in the file name (ceiling_train_seed<k>.npz); pass --set-seeds")
    return int(m.group(1))


def find_pours(world: Any, paths: Sequence[Path], seeds: Sequence[int]) -> list[dict]:
    """Every partial first pour of the sets, with what re-executing it needs: its problem (start, plant
    jitter), its action prefix, the env slot it ran in (:func:`active.ladder.ceiling_dataset` runs batches
    of ``CEILING_BATCH`` in order), its recorded pre- and post-pour states."""
    from active.ladder import CEILING_BATCH, ceiling_train_problems

    from .admission import partial_first_pours

    pours = []
    for path, seed in zip(paths, seeds):
        if not Path(path).exists():
            raise FileNotFoundError(f"--sets {path}: no such file")
        with np.load(path) as f:
            s, a, s2, traj, n = f["s"], f["a"], f["s_next"], f["trajectory"], len(f["category"])
        probs = ceiling_train_problems(world, n, seed)
        for j in np.flatnonzero(partial_first_pours(s, a, s2)):
            i = int(traj[j])
            first = int(np.flatnonzero(traj == i)[0])
            if not np.allclose(s[first, :3], probs[i].start[:3], atol=1e-6):
                raise ValueError(
                    f"--sets {path}: trajectory {i} starts at {s[first, :3]}, not at the start of "
                    f"ladder seed {seed}'s problem {i} ({probs[i].start[:3]}); pass the right --set-seeds"
                )
            pours.append(
                {
                    "set": str(path),
                    "trajectory": i,
                    "step": j - first,
                    "slot": i % CEILING_BATCH,
                    "start": probs[i].start[:3],
                    "plant_jitter": probs[i].plant_jitter,
                    "prefix": a[first : j + 1],
                    "pre": s[j],
                    "recorded": s2[j],
                }
            )
    return pours


def execute(executor: Any, world_name: str, jobs: list[tuple], what: str) -> list[np.ndarray | None]:
    """Final states of (start, actions, plant jitter, slot) jobs in batches of 32 (None where the start
    overlaps an obstacle, e.g. a jittered plant, or the trajectory did not run to its end)."""
    from active.ladder import CEILING_BATCH

    t0 = time.perf_counter()
    hits = executor.start_obstacles(world_name, np.array([j[0] for j in jobs]), np.array([j[2] for j in jobs]))
    ok = [h is None for h in hits]
    run = [j for j, k in zip(jobs, ok) if k]
    res = []
    for c in range(0, len(run), CEILING_BATCH):
        ch = run[c : c + CEILING_BATCH]
        res += executor.run(
            world_name,
            np.array([j[0] for j in ch]),
            [j[1] for j in ch],
            plant_jitter=np.array([j[2] for j in ch]),
            slots=[j[3] for j in ch],
        )
    it = iter(res)
    out = []
    for j, k in zip(jobs, ok):
        r = next(it) if k else None
        out.append(r.states[-1] if r is not None and len(r.states) == len(j[1]) + 1 else None)
    print(
        f"{what}: {len(jobs)} executions ({len(jobs) - sum(ok)} starts overlap), {time.perf_counter() - t0:.0f} s",
        flush=True,
    )
    return out


def from_rest(pre: np.ndarray, pour: np.ndarray, move_range: dict) -> np.ndarray:
    """The pour alone from rest: a move to where the cup already is (one settle), then the pour. The observed
    pose is float32, so a pose on the move range's edge can lie a rounding outside it: clipped into
    ``move_range`` (``skills.move``). Moves end on ``skills.lattice``: a pour that is its trajectory's first
    action, from an off-lattice start, is poured from the nearest lattice point."""
    from sim.skills import move

    x, y = (float(np.clip(v, *move_range[k])) for v, k in zip(pre[:2], ("x", "y")))
    return np.array([move(x, y), np.asarray(pour, float)])


def take_apart(
    sets: Sequence[Path],
    set_seeds: Sequence[int] | None,
    overrides: Sequence[str],
    slots: int,
    jitters: int,
    mde_files: Sequence[Path],
) -> dict[str, Any]:
    """Execute every partial first pour of ``sets`` again (history, rest, source world, plant poses; module
    docstring) and return the per-pour outcomes and labels with their summary. Arguments are checked, and
    the MDE files looked for, before anything is simulated."""
    import torch

    from active.planner_setup import planning_dynamics
    from active.run import compose_config
    from active.settings import read_settings
    from sim.execute import PouringExecutor
    from task import state_distance
    from task.problems import draw_plant_jitter

    if not 1 <= slots <= 1 + len(EXTRA_SLOTS):
        raise ValueError(f"--slots {slots}: allowed 1..{1 + len(EXTRA_SLOTS)}")
    if jitters < 1:
        raise ValueError(f"--jitters {jitters}: allowed >= 1")
    if set_seeds is not None and len(set_seeds) != len(sets):
        raise ValueError(f"--set-seeds: {len(set_seeds)} seeds for {len(sets)} --sets")
    missing = [str(f) for f in mde_files if not Path(f).exists()]
    if missing:
        raise FileNotFoundError(f"--mde: no such file: {missing}")
    t_all = time.perf_counter()
    cfg = compose_config(list(overrides))
    settings = read_settings(cfg, method="all")
    exp, world = settings.exp, settings.world
    dyn = planning_dynamics(settings.dynamics, world, exp)
    seeds = [set_seed(Path(p), None if set_seeds is None else set_seeds[k]) for k, p in enumerate(sets)]
    pours = find_pours(world, sets, seeds)
    if not pours:
        raise ValueError(f"--sets {[str(p) for p in sets]}: no partial first pours")
    print(f"{len(pours)} partial first pours in {len(sets)} sets", flush=True)
    with torch.no_grad():
        pred = dyn.predict(
            torch.as_tensor(np.stack([p["pre"] for p in pours]), dtype=torch.float32),
            torch.as_tensor(np.stack([p["prefix"][-1] for p in pours]), dtype=torch.float32),
        )
    pred = pred.double().numpy()

    ex = PouringExecutor(world)
    rng = np.random.default_rng(2027)
    jit = [np.zeros(3)] + [draw_plant_jitter(world.plant, rng) for _ in range(jitters)]
    zero = np.zeros(3)

    def rest(p: dict) -> np.ndarray:
        return from_rest(p["pre"], p["prefix"][-1], world.skills["move"])

    def slots_of(p: dict) -> list[int]:
        return [p["slot"], *EXTRA_SLOTS[: slots - 1]]

    runs = {
        "history": (
            "target",
            [(p["start"], p["prefix"], p["plant_jitter"], sl) for p in pours for sl in slots_of(p)],
            slots,
        ),
        "rest": (
            "target",
            [(p["pre"][:3], rest(p), p["plant_jitter"], sl) for p in pours for sl in slots_of(p)],
            slots,
        ),
        "source": ("source", [(p["pre"][:3], rest(p), zero, sl) for p in pours for sl in slots_of(p)], slots),
        "jitter": ("target", [(p["pre"][:3], rest(p), j, p["slot"]) for p in pours for j in jit], len(jit)),
    }
    outcomes = {}
    for name, (world_name, jobs, per) in runs.items():
        flat = execute(ex, world_name, jobs, name)
        outcomes[name] = [flat[k * per : (k + 1) * per] for k in range(len(pours))]
    ex.close()

    def label(p: np.ndarray, q: np.ndarray | None) -> float:
        return np.nan if q is None else float(state_distance(p[None], q[None], world.distance_weights)[0])

    rows = []
    for k, p in enumerate(pours):
        row = {
            "set": p["set"],
            "trajectory": p["trajectory"],
            "step": p["step"],
            "slot": p["slot"],
            "x": float(p["pre"][0]),
            "y": float(p["pre"][1]),
            "theta": float(p["prefix"][-1][1]),
            "hold": float(p["prefix"][-1][2]),
            "action": p["prefix"][-1].tolist(),
            "pre": p["pre"].tolist(),
            "recorded": p["recorded"].tolist(),
            "model": pred[k].tolist(),
            "label_recorded": label(pred[k], p["recorded"]),
        }
        for name in runs:
            finals = outcomes[name][k]
            row[name] = [None if f is None else f.tolist() for f in finals]
            row[f"labels_{name}"] = [label(pred[k], f) for f in finals]
        lj = np.array(row["labels_jitter"][1:])
        lj = lj[np.isfinite(lj)]
        row["jitter_share_good"] = float(np.mean(lj < exp.d_max)) if len(lj) else None
        rows.append(row)
    summary = summarise(rows, exp.d_max)
    if mde_files:
        summary["mde"] = mde_at_safe_pours(rows, mde_files, exp)
    return {
        "sets": [str(p) for p in sets],
        "set_seeds": seeds,
        "overrides": list(overrides),
        "slots": slots,
        "plant_jitters": [j.tolist() for j in jit],
        "d_max": exp.d_max,
        "summary": summary,
        "pours": rows,
        "seconds": time.perf_counter() - t_all,
    }


def _fraction_stats(rows: list[dict], run: str, i: int) -> dict[str, np.ndarray]:
    """Per pour: mean and std over the run's executions of state component i (NaN where none ran)."""

    def one(r: dict) -> tuple[float, float]:
        v = np.array([f[i] for f in r[run] if f is not None])
        return (float(v.mean()), float(v.std())) if len(v) else (np.nan, np.nan)

    m, s = np.array([one(r) for r in rows]).T
    return {"mean": m, "std": s}


def summarise(rows: list[dict], d_max: float) -> dict[str, Any]:
    """Medians over the pours: labels, the model's error, history against rest, slot scatter, jitter verdicts."""
    med = lambda v: float(np.nanmedian(v))  # noqa: E731
    model = np.array([r["model"] for r in rows])
    out: dict[str, Any] = {
        "pours": len(rows),
        "replay_max_abs_diff": float(
            np.nanmax(
                [
                    np.abs(np.array(r["history"][0]) - r["recorded"]).max() if r["history"][0] is not None else np.nan
                    for r in rows
                ]
            )
        ),
    }
    tgt = {run: _fraction_stats(rows, run, 4) for run in ("history", "rest", "source")}
    src = {run: _fraction_stats(rows, run, 3) for run in ("history", "rest", "source")}
    for run in ("history", "rest", "source"):
        lab = np.array([np.nanmean(r[f"labels_{run}"]) for r in rows])
        out[run] = {
            "label_median": med(lab),
            "label_share_good": float(np.mean(lab < d_max)),
            "model_error_target_cup": med(np.abs(model[:, 4] - tgt[run]["mean"])),
            "model_error_target_cup_signed": med(model[:, 4] - tgt[run]["mean"]),
            "model_error_poured_cup": med(np.abs(model[:, 3] - src[run]["mean"])),
            "slot_std_target_cup": med(tgt[run]["std"]),
        }
    out["label_recorded_median"] = med([r["label_recorded"] for r in rows])
    d = tgt["history"]["mean"] - tgt["rest"]["mean"]
    e_h, e_r = model[:, 4] - tgt["history"]["mean"], model[:, 4] - tgt["rest"]["mean"]
    ok = np.isfinite(e_h) & np.isfinite(e_r)
    out["history_minus_rest_target_cup"] = {
        "median_abs": med(np.abs(d)),
        "median": med(d),
        "corr_model_errors": float(np.corrcoef(e_h[ok], e_r[ok])[0, 1]),
    }
    same = np.abs(tgt["rest"]["mean"] - tgt["source"]["mean"]) < 1e-9
    out["target_rest_equals_source"] = int(np.sum(same))
    share = np.array([np.nan if r["jitter_share_good"] is None else r["jitter_share_good"] for r in rows])
    good_labels = [v for r in rows for v in r["labels_jitter"][1:] if np.isfinite(v) and v < d_max]
    out["jitter"] = {
        "always_good": int(np.sum(share == 1)),
        "always_bad": int(np.sum(share == 0)),
        "mixed": int(np.sum((share > 0) & (share < 1))),
        "share_good_mean": float(np.nanmean(share)),
        "good_without_jitter": float(
            np.mean([r["labels_jitter"][0] < d_max for r in rows if np.isfinite(r["labels_jitter"][0])])
        ),
        "label_of_good_outcomes_median": med(good_labels) if good_labels else None,
    }
    return out


def mde_at_safe_pours(rows: list[dict], files: Sequence[Path], exp: Any) -> list[dict]:
    """Each MDE at the pours good under every plant jitter: median mean, std, noise std, share admitted."""
    import torch

    import mde as mde_pkg

    safe = [r for r in rows if r["jitter_share_good"] == 1]
    if not safe:
        return []
    X = torch.tensor([r["pre"] + r["action"] for r in safe], dtype=torch.float64)  # planner.features: (s, a)
    out = []
    for f in files:
        m = mde_pkg.load(f)
        mu, sd = (v.double().numpy() for v in m.predict(X))
        noise = m.noise_std(X).double().numpy()
        out.append(
            {
                "file": str(f),
                "n": len(safe),
                "mu_median": float(np.median(mu)),
                "std_median": float(np.median(sd)),
                "noise_std_median": float(np.median(noise)),
                "admitted": float(np.mean(mu + exp.beta_test * sd < exp.d_max)),
            }
        )
    return out


def format_table(r: dict[str, Any]) -> str:
    s = r["summary"]
    lines = [
        f"{s['pours']} partial first pours; replay of the recorded history: max |difference| "
        f"{s['replay_max_abs_diff']:.2g}; {s['target_rest_equals_source']} from rest end exactly as in the source world",  # noqa: E501 (a table row's format reads best on one line)
        f"{'executed':<10} {'label med':>9} {'< d_max':>8} {'|model-tgt|':>11} {'signed':>7} {'|model-src|':>11} "
        f"{'slot std':>8}",
        f"{'recorded':<10} {s['label_recorded_median']:>9.4f}",
    ]
    for run in ("history", "rest", "source"):
        v = s[run]
        lines.append(
            f"{run:<10} {v['label_median']:>9.4f} {v['label_share_good']:>8.2f} {v['model_error_target_cup']:>11.4f} "
            f"{v['model_error_target_cup_signed']:>+7.4f} {v['model_error_poured_cup']:>11.4f} {v['slot_std_target_cup']:>8.4f}"  # noqa: E501 (a table row's format reads best on one line)
        )
    h = s["history_minus_rest_target_cup"]
    lines.append(
        f"history - rest (target cup): median |.| {h['median_abs']:.4f}, median {h['median']:+.4f}; "
        f"corr of the model's errors {h['corr_model_errors']:.2f}"
    )
    j = s["jitter"]
    lines.append(
        f"under {len(r['plant_jitters']) - 1} plant jitters: always good {j['always_good']}, always bad "
        f"{j['always_bad']}, mixed {j['mixed']}; share good {j['share_good_mean']:.2f} (no jitter "
        f"{j['good_without_jitter']:.2f}); median label of the good outcomes {j['label_of_good_outcomes_median']:.4f}"
    )
    for m in s.get("mde", []):
        lines.append(
            f"MDE {m['file']}: at the {m['n']} always-good pours mu {m['mu_median']:.3f} std {m['std_median']:.3f} "
            f"(noise {m['noise_std_median']:.3f}), admitted {m['admitted']:.2f}"
        )
    return "\n".join(lines)


def plot(r: dict[str, Any], path: Path) -> Path:
    """Two panels: where the pours were made, coloured by the share of plant poses under which they stay good;
    each pour's labels (under every plant pose, from rest) against the cup's x, with d_max."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, d_max = r["pours"], r["d_max"]
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4.2))
    share = np.array([np.nan if p["jitter_share_good"] is None else p["jitter_share_good"] for p in rows])
    sc = a0.scatter(
        [p["x"] for p in rows],
        [p["y"] for p in rows],
        c=share,
        cmap="RdYlGn",
        vmin=0,
        vmax=1,
        s=[40 + 200 * (p["theta"] - 1.0) for p in rows],
        edgecolors="k",
        linewidths=0.4,
    )
    fig.colorbar(sc, ax=a0, label="share of plant poses with label < d_max")
    a0.set(
        xlabel="cup x before the pour (m)",
        ylabel="cup y (m)",
        title=f"{len(rows)} partial first pours (marker size: tilt)",
    )
    for p in rows:
        lab = np.array(p["labels_jitter"][1:], float)
        x = np.full(len(lab), p["x"]) + np.linspace(-0.003, 0.003, len(lab))
        a1.scatter(
            x,
            np.clip(lab, 1e-3, None),
            s=6,
            color="tab:red" if 0 < (p["jitter_share_good"] or 0) < 1 else "tab:blue",
            alpha=0.6,
        )
    a1.axhline(d_max, color="k", ls="--", lw=1, label=f"d_max = {d_max}")
    a1.set(
        yscale="log",
        xlabel="cup x before the pour (m)",
        ylabel="label d(model, executed)",
        title="labels under 8 plant poses (red: the pose decides)",
    )
    a1.legend(loc="upper right")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.partial_pours", description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=Path, nargs="+", default=[], help="saved ceiling sets (ceiling_train_seed<k>.npz)")
    ap.add_argument(
        "--set-seeds",
        type=int,
        nargs="+",
        default=None,
        help="the ladder seed of each set (default: from its file name)",
    )
    ap.add_argument("--slots", type=int, default=5, help="env slots per execution (default 5)")
    ap.add_argument("--jitters", type=int, default=8, help="fresh plant-pose jitters (default 8)")
    ap.add_argument("--mde", type=Path, nargs="*", default=[], help="saved MDEs to read at the always-good pours")
    ap.add_argument(
        "--override",
        dest="overrides",
        action="append",
        default=[],
        help="Hydra override of the config the sets were made with (repeatable)",
    )
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument("--plot", type=Path, default=None, help="draw the pours and their labels here (PNG)")
    ap.add_argument("--from-json", type=Path, default=None, help="re-read an earlier --out instead of simulating")
    args = ap.parse_args(argv)
    if not args.sets and args.from_json is None:
        ap.error("give --sets (or --from-json)")
    if args.from_json is not None:
        with open(args.from_json) as fh:
            r = json.load(fh)
    else:
        r = take_apart(args.sets, args.set_seeds, args.overrides, args.slots, args.jitters, args.mde)
    report(format_table(r), r, args.out)
    if args.plot is not None:
        print(f"wrote {plot(r, args.plot)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
