"""Speed benchmark of the MDE: fit time and batched prediction throughput.

    python -m benchmarks.mde [--sizes 200 1200 3000] [--out bench_mde.json]

Synthetic data, d = 7, with input-dependent noise (the case the heteroscedastic GP is for).
Prediction is timed on the model fitted with the size closest to 1200 (the paper protocol's
final dataset: 20 iterations x 10 trajectories x <= 6 steps), at batch 1 and 10 000, in the
configured predict dtype and in the other one for comparison. Targets on a 2-core CPU:
fit(1200) <= 30 s and predict(10 000) <= 0.2 s.

The figures are only meaningful on an otherwise idle CPU: with other busy processes on 2 cores,
two OpenMP threads wait on each other and everything gets 2-10x slower and erratic; the table
prints the load average. On a shared machine run it as ``OMP_WAIT_POLICY=PASSIVE python -m
benchmarks.mde`` (GNU OpenMP reads it at start-up; spinning threads are what hurts) or with
``--threads 1``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import torch

import safeio
from mde.model import GPMDE

TARGET_FIT_1200_S = 30.0
TARGET_PREDICT_10K_S = 0.2


def synthetic(n: int, d: int = 7, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Deviation-like data: smooth non-negative mean, noise std growing along x0 and x1."""
    g = torch.Generator().manual_seed(seed)
    X = torch.rand(n, d, generator=g, dtype=torch.float64)
    if d < 2:
        raise ValueError(f"synthetic data needs d >= 2, got {d}")
    rest = X[:, 2:].mean(dim=1) if d > 2 else torch.zeros(n, dtype=X.dtype)
    f = 0.05 + 0.04 * torch.sin(3.0 * X[:, 0]) + 0.03 * X[:, 1] ** 2 + 0.02 * rest
    s = 0.002 + 0.03 * X[:, 0] * X[:, 1]
    y = (f + s * torch.randn(n, generator=g, dtype=torch.float64)).clamp_min(0.0)
    return X, y


def _time_predict(mde: GPMDE, X: torch.Tensor, repeats: int) -> float:
    mde.predict(X)  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        mde.predict(X)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def run(sizes: Sequence[int] = (200, 1200, 3000), batch: int = 10_000, d: int = 7, **config: Any) -> dict[str, Any]:
    """Run the benchmark and return a JSON-able dict."""
    load_before = _loadavg()
    fits = []
    models = {}
    for n in sizes:
        X, y = synthetic(n, d, seed=n)
        t = time.perf_counter()
        mde = GPMDE(**config).fit(X, y)
        fit_s = time.perf_counter() - t
        models[n] = mde
        info = mde.fit_info
        fits.append(
            {
                "n": n,
                "fit_s": fit_s,
                "n_fit_points": info.get("n_fit_points"),
                "iterations": len(info.get("log_ml_history", [])),
                "selected_iteration": info.get("selected_iteration"),
                "log_ml": (info.get("log_ml_history") or [info.get("homoscedastic_log_ml")])[
                    max(0, (info.get("selected_iteration") or 1) - 1)
                ],
            }
        )
        print(f"fit n={n}: {fit_s:.2f} s", flush=True)

    n_pred = min(sizes, key=lambda n: abs(n - 1200))
    base = models[n_pred]
    Xq, _ = synthetic(batch, d, seed=12345)
    preds = []
    for dtype in (base.config.predict_dtype, "float64" if base.config.predict_dtype == "float32" else "float32"):
        mde = base if dtype == base.config.predict_dtype else _with_predict_dtype(base, dtype)
        for b, repeats in ((1, 200), (batch, 5)):
            sec = _time_predict(mde, Xq[:b], repeats)
            preds.append({"n_train": n_pred, "batch": b, "dtype": dtype, "seconds": sec, "points_per_s": b / sec})
    # accuracy of the other dtype relative to float64
    ref = base if base.config.predict_dtype == "float64" else _with_predict_dtype(base, "float64")
    f32 = base if base.config.predict_dtype == "float32" else _with_predict_dtype(base, "float32")
    m64, s64 = ref.predict(Xq)
    m32, s32 = f32.predict(Xq)
    result = {
        "machine": {
            "platform": platform.platform(),
            "cpu_count": os.cpu_count(),
            "torch_threads": base.config.num_threads or torch.get_num_threads(),
            "torch": torch.__version__,
            # 1-minute load average before / after: on a shared CPU other processes' load
            # inflates every figure here (see the module docstring)
            "loadavg_1min": [load_before, _loadavg()],
            "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY"),
        },
        "config": base.config.to_dict(),
        "d": d,
        "fit": fits,
        "predict": preds,
        "float32_vs_float64": {
            "max_abs_mean_diff_over_label_std": float((m32 - m64).abs().max() / base.label_std),
            "max_rel_std_diff": float(((s32 - s64).abs() / s64).max()),
        },
        "targets": {"fit_1200_s": TARGET_FIT_1200_S, "predict_10000_s": TARGET_PREDICT_10K_S},
    }
    return result


def _loadavg() -> float | None:
    try:
        return os.getloadavg()[0]
    except OSError:  # not available on every platform
        return None


def _with_predict_dtype(mde: GPMDE, dtype: str) -> GPMDE:
    """Same fitted model, caches rebuilt in another dtype (no refit)."""
    import copy

    other = copy.copy(mde)
    other._config = type(mde.config).from_dict(dict(mde.config.to_dict(), predict_dtype=dtype))
    f = mde._fitted
    other._fitted = other._make_fitted(
        f.X, f.y, f.bounds, f.mean_model, f.train_Yvar, f.noise_model, f.noise_train, f.info
    )
    return other


def format_table(result: dict[str, Any]) -> str:
    mach = result["machine"]
    load = ", ".join("-" if v is None else f"{v:.2f}" for v in mach["loadavg_1min"])
    lines = [
        f"MDE benchmark: d={result['d']}, {mach['cpu_count']} CPUs, {mach['torch_threads']} torch threads, "
        f"load average (1 min) before/after: {load}, OMP_WAIT_POLICY={mach.get('OMP_WAIT_POLICY')}"
    ]
    lines.append(f"{'n':>6} {'fit [s]':>9} {'fit pts':>8} {'iters':>6} {'best':>5} {'log ML/pt':>10}")
    for r in result["fit"]:
        lines.append(
            f"{r['n']:>6} {r['fit_s']:>9.2f} {r['n_fit_points']:>8} {r['iterations']:>6} "
            f"{r['selected_iteration']:>5} {r['log_ml']:>10.4f}"
        )
    lines.append("")
    lines.append(f"{'n_train':>7} {'batch':>6} {'dtype':>8} {'time [ms]':>10} {'points/s':>12}")
    for r in result["predict"]:
        lines.append(
            f"{r['n_train']:>7} {r['batch']:>6} {r['dtype']:>8} {r['seconds'] * 1e3:>10.2f} {r['points_per_s']:>12.0f}"
        )
    acc = result["float32_vs_float64"]
    lines.append(
        f"float32 vs float64: max |mean diff| / label std = {acc['max_abs_mean_diff_over_label_std']:.2e}, "
        f"max relative std diff = {acc['max_rel_std_diff']:.2e}"
    )
    fit1200 = [r["fit_s"] for r in result["fit"] if r["n"] == 1200]
    pred = [
        r["seconds"]
        for r in result["predict"]
        if r["batch"] == 10_000 and r["dtype"] == result["config"]["predict_dtype"]
    ]
    if fit1200:
        ok = "met" if fit1200[0] <= TARGET_FIT_1200_S else "MISSED"
        lines.append(f"target fit(1200) <= {TARGET_FIT_1200_S:g} s: {fit1200[0]:.2f} s ({ok})")
    if pred:
        ok = "met" if pred[0] <= TARGET_PREDICT_10K_S else "MISSED"
        lines.append(f"target predict(10 000) <= {TARGET_PREDICT_10K_S:g} s: {pred[0]:.3f} s ({ok})")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.mde", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[200, 1200, 3000])
    parser.add_argument("--batch", type=int, default=10_000)
    parser.add_argument("--d", type=int, default=7)
    parser.add_argument("--predict-dtype", choices=("float32", "float64"), default=None)
    parser.add_argument("--threads", type=int, default=0, help="MDEConfig.num_threads (0: torch's setting)")
    parser.add_argument("--out", default="bench_mde.json")
    args = parser.parse_args(argv)
    config = {"num_threads": args.threads}
    if args.predict_dtype is not None:
        config["predict_dtype"] = args.predict_dtype
    result = run(args.sizes, args.batch, args.d, **config)
    print(format_table(result))
    out = Path(args.out)
    safeio.write_json(out, result, indent=2)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
