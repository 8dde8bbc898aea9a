"""Table 1's reconstruction row against the number of fitting iterations: what the default (900 Adam steps,
one frame each, the first 600 at half resolution) leaves on the table, and what the paper's SSIM and LPIPS
cost on two CPU cores.

``eval_self`` (the protocol of ``bench_table1.py``, target ``reconstruction``) on one clip with
``ReconstructOptions(iterations=N)`` for each N (and, with ``--ssim-weights``, each weight of the D-SSIM term;
with ``--coarse-fractions``, each share of the steps fitted at half resolution first);
PSNR, SSIM, LPIPS over whole frames as Table 1 reports them, compared with the paper's SpaT figures at its two
decimals, and the wall time of the whole evaluation. Writes ``docs/benchmarks/iterations.md`` (or ``--doc``).

    flock /tmp/marionette-bench.lock python benchmarks/bench_iterations.py \
        [--clip car-turn] [--iterations 900,2400] [--coarse-fractions 0,0.6667]
        [--ssim-weights 0,0.2 --doc docs/benchmarks/ssim_loss.md]
        [--coarse-fractions 0,0.5 --doc docs/benchmarks/coarse_to_fine.md]
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
    parser.add_argument("--iterations", default="900,2400")
    parser.add_argument("--ssim-weights", default=None,
                        help="comma-separated ssim_weight values (default: the option's default only)")
    parser.add_argument("--coarse-fractions", default=None,
                        help="comma-separated coarse_fraction values (default: the option's default only)")
    parser.add_argument("--doc", type=Path, default=OUT)
    parser.add_argument("--out", type=Path, default=Path("/tmp/marionette-iterations"))
    args = parser.parse_args()
    if not table1.DATA.is_dir():
        raise SystemExit(f"{table1.DATA} not found: this benchmark needs ../shared/data")
    warnings.simplefilter("ignore")
    args.out.mkdir(parents=True, exist_ok=True)
    category, _, _, parts, (psnr_p, ssim_p, lpips_p) = table1.CASES[args.clip]
    defaults = ReconstructOptions()
    source, masks = table1.source_of(args.clip)
    title = "# Reconstruction iterations and Table 1" + ("" if args.ssim_weights is None else ", the D-SSIM term") \
        + ("" if args.coarse_fractions is None else ", a half-resolution start")
    lines = [title, "",
             f"`python benchmarks/bench_iterations.py --clip {args.clip} --iterations {args.iterations}"
             + ("" if args.ssim_weights is None else f" --ssim-weights {args.ssim_weights}")
             + ("" if args.coarse_fractions is None else f" --coarse-fractions {args.coarse_fractions}")
             + ("" if args.doc == OUT else f" --doc {args.doc.resolve().relative_to(ROOT)}") + "` on "
             f"{platform.machine()}, 2 cores. `eval_self` (Table 1's protocol, target *reconstruction*, fitted to "
             "every frame, the focal length estimated from the clip) with "
             "`ReconstructOptions(iterations=N, ssim_weight=λ, coarse_fraction=c)`; the defaults "
             f"are {defaults.iterations}, {defaults.ssim_weight:g} and {defaults.coarse_fraction:g} (λ: the D-SSIM "
             "term's weight; c: the share of the steps fitted at half resolution first). *Fit*: seconds of the "
             "reconstruction; *seconds*: the whole evaluation (extraction, fit, render, metrics), one run each. "
             f"Paper SpaT ({category}): PSNR {psnr_p}, SSIM {ssim_p}, LPIPS {lpips_p}; SSIM and LPIPS compared "
             "at its two decimals.", "",
             "| iterations | λ | c | PSNR (dB) | SSIM | LPIPS | SSIM vs paper | LPIPS vs paper | fit | seconds |",
             "|---:|---:|---:|---:|---:|---:|---|---|---:|---:|"]

    def values(text: str | None, default: float) -> list[float]:
        return [default] if text is None else [float(v) for v in text.split(",") if v]

    runs = [(int(n), w, c) for n in args.iterations.split(",") if n
            for w in values(args.ssim_weights, defaults.ssim_weight)
            for c in values(args.coarse_fractions, defaults.coarse_fraction)]
    for n, weight, coarse in runs:
        start = time.perf_counter()
        reporter = Reporter(quiet=True)
        m = eval_self(source, masks, args.out / f"{args.clip}_{n}_{weight:g}_{coarse:g}", target="reconstruction",
                      reporter=reporter, options=dataclasses.replace(EVAL_EXTRACT, parts=parts),
                      reconstruct_options=ReconstructOptions(iterations=n, ssim_weight=weight,
                                                             coarse_fraction=coarse))
        seconds = time.perf_counter() - start
        lpips = m["lpips"]
        lines.append(f"| {n} | {weight:g} | {coarse:g} | {m['psnr']:.2f} | {m['ssim']:.4f} | "
                     f"{'skipped' if lpips is None else f'{lpips:.4f}'} | {table1.verdict(m['ssim'], ssim_p)} | "
                     f"{'–' if lpips is None else table1.verdict(lpips, lpips_p, lower_is_better=True)} | "
                     f"{reporter.timings.get('reconstruction', float('nan')):.0f} | {seconds:.0f} |")
        print(lines[-1], flush=True)
    args.doc.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.doc}")


if __name__ == "__main__":
    main()
