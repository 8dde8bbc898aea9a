"""Table 1's reconstruction row against the number of fitting iterations: what the default (600 Adam steps,
one frame each) leaves on the table, and what the paper's SSIM and LPIPS cost on two CPU cores.

``eval_self`` (the protocol of ``bench_table1.py``, target ``reconstruction``) on one clip with
``ReconstructOptions(iterations=N)`` for each N (and, with ``--ssim-weights``, each weight of the D-SSIM term);
PSNR, SSIM, LPIPS over whole frames as Table 1 reports them, compared with the paper's SpaT figures at its two
decimals, and the wall time of the whole evaluation. Writes ``docs/benchmarks/iterations.md`` (or ``--doc``).

    flock /tmp/marionette-bench.lock python benchmarks/bench_iterations.py \
        [--clip car-turn] [--iterations 600,2400,4800] [--ssim-weights 0,0.2 --doc docs/benchmarks/ssim_loss.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "benchmarks" / "iterations.md"


def main() -> None:
    import bench_table1 as table1

    from marionette.eval import EVAL_EXTRACT, eval_self
    from marionette.progress import Reporter
    from marionette.reconstruct import ReconstructOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", default="car-turn", choices=[n for n, c in table1.CASES.items() if c[4]])
    parser.add_argument("--iterations", default="600,2400,4800")
    parser.add_argument("--ssim-weights", default=None,
                        help="comma-separated ssim_weight values (default: the option's default only)")
    parser.add_argument("--doc", type=Path, default=OUT)
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-iterations"))
    args = parser.parse_args()
    if not table1.DATA.is_dir():
        raise SystemExit(f"{table1.DATA} not found: this benchmark needs ../shared/data")
    warnings.simplefilter("ignore")
    args.out.mkdir(parents=True, exist_ok=True)
    category, _, _, parts, (psnr_p, ssim_p, lpips_p) = table1.CASES[args.clip]
    source, masks = table1.source_of(args.clip)
    lines = ["# Reconstruction iterations and Table 1", "",
             f"`python benchmarks/bench_iterations.py --clip {args.clip} --iterations {args.iterations}"
             + ("" if args.ssim_weights is None else
                f" --ssim-weights {args.ssim_weights} --doc {args.doc.resolve().relative_to(ROOT)}") + "` on "
             f"{platform.machine()}, 2 cores. `eval_self` (Table 1's protocol, target *reconstruction*, fitted to "
             "every frame) with `ReconstructOptions(iterations=N, ssim_weight=λ)`; the defaults are 600 and "
             f"{ReconstructOptions().ssim_weight:g} (λ: the D-SSIM term's weight). Seconds: the whole "
             f"evaluation (extraction, fit, render, metrics). Paper SpaT ({category}): PSNR {psnr_p}, SSIM "
             f"{ssim_p}, LPIPS {lpips_p}; SSIM and LPIPS compared at its two decimals.", "",
             "| iterations | λ | PSNR (dB) | SSIM | LPIPS | SSIM vs paper | LPIPS vs paper | seconds |",
             "|---:|---:|---:|---:|---:|---|---|---:|"]
    weights = [ReconstructOptions().ssim_weight] if args.ssim_weights is None else \
        [float(v) for v in args.ssim_weights.split(",") if v]
    for n, weight in [(n, w) for n in (int(v) for v in args.iterations.split(",") if v) for w in weights]:
        start = time.perf_counter()
        m = eval_self(source, masks, args.out / f"{args.clip}_{n}_{weight:g}", target="reconstruction",
                      reporter=Reporter(quiet=True), options=dataclasses.replace(EVAL_EXTRACT, parts=parts),
                      reconstruct_options=ReconstructOptions(iterations=n, ssim_weight=weight))
        seconds = time.perf_counter() - start
        lpips = m["lpips"]
        lines.append(f"| {n} | {weight:g} | {m['psnr']:.2f} | {m['ssim']:.3f} | "
                     f"{'skipped' if lpips is None else f'{lpips:.3f}'} | {table1.verdict(m['ssim'], ssim_p)} | "
                     f"{'–' if lpips is None else table1.verdict(lpips, lpips_p, lower_is_better=True)} | "
                     f"{seconds:.0f} |")
        print(lines[-1], flush=True)
    args.doc.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
