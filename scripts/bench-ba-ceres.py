#!/usr/bin/env python3
"""Runs pycolmap's Ceres bundle adjustment on a COLMAP model folder and prints
time and cost, to set beside colslam-optim's numbers on the same data.

    cargo run --release -p colslam-optim --example bench_ba -- --export /tmp/ba
    .venv/bin/python scripts/bench-ba-ceres.py /tmp/ba/large_100x20000 --loss cauchy --scale 1

The model is read, adjusted in memory and not written back. By default the
solver tolerances are set to Ceres' own defaults (function 1e-6, gradient
1e-10, parameter 1e-8), which colslam-optim also uses; --colmap-tolerances
keeps COLMAP's (0, 1e-4, 0). The gauge is COLMAP's TWO_CAMS_FROM_WORLD
(or none with --gauge none).
"""

import argparse
import json
import sys
import time

import pycolmap

LOSSES = {
    "trivial": pycolmap.LossFunctionType.TRIVIAL,
    "huber": pycolmap.LossFunctionType.HUBER,
    "cauchy": pycolmap.LossFunctionType.CAUCHY,
    "soft_l1": pycolmap.LossFunctionType.SOFT_L1,
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model", help="COLMAP model folder (cameras/images/points3D .txt or .bin)")
    ap.add_argument("--loss", choices=sorted(LOSSES), default="cauchy")
    ap.add_argument("--scale", type=float, default=1.0, help="loss scale in pixels (default 1)")
    ap.add_argument("--threads", type=int, default=-1, help="Ceres threads (-1: all cores)")
    ap.add_argument("--max-iterations", type=int, default=100)
    ap.add_argument("--colmap-tolerances", action="store_true",
                    help="keep COLMAP's tolerances instead of Ceres' defaults")
    ap.add_argument("--gauge", choices=["two_cams", "none"], default="two_cams",
                    help="COLMAP's TWO_CAMS_FROM_WORLD gauge, or none (free gauge, LM damping only)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    ap.add_argument("--fixed-intrinsics", action="store_true", help="do not refine focal length and extra params")
    args = ap.parse_args()

    rec = pycolmap.Reconstruction(args.model)
    opts = pycolmap.BundleAdjustmentOptions()
    opts.print_summary = False
    opts.refine_focal_length = not args.fixed_intrinsics
    opts.refine_extra_params = not args.fixed_intrinsics
    opts.refine_principal_point = False
    opts.ceres.loss_function_type = LOSSES[args.loss]
    opts.ceres.loss_function_scale = args.scale
    so = opts.ceres.solver_options
    so.num_threads = args.threads
    so.max_num_iterations = args.max_iterations
    if not args.colmap_tolerances:
        so.function_tolerance = 1e-6
        so.gradient_tolerance = 1e-10
        so.parameter_tolerance = 1e-8

    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    if args.gauge == "two_cams":
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)

    t0 = time.perf_counter()
    adjuster = pycolmap.create_default_bundle_adjuster(opts, config, rec)
    t1 = time.perf_counter()
    c1 = time.process_time()
    summary = adjuster.solve()
    t2 = time.perf_counter()
    c2 = time.process_time()
    ceres = getattr(summary, "ceres_summary", None)
    if args.json:
        out = {"num_residuals": summary.num_residuals, "solve_wall_s": t2 - t1, "solve_cpu_s": c2 - c1}
        if ceres is not None:
            out.update(initial_cost=ceres.initial_cost, final_cost=ceres.final_cost,
                       iterations=ceres.num_successful_steps + ceres.num_unsuccessful_steps,
                       successful_steps=ceres.num_successful_steps,
                       linear_solver=str(ceres.linear_solver_type_used), termination=str(ceres.termination_type))
        print(json.dumps(out))
        return 0
    print(f"model: {args.model}")
    print(f"images {rec.num_reg_images()}, points {rec.num_points3D()}, residuals {summary.num_residuals}")
    print(f"loss {args.loss}({args.scale}), threads {args.threads}")
    print(f"setup {t1 - t0:.3f} s, solve {t2 - t1:.3f} s wall, {c2 - c1:.2f} s CPU")
    if ceres is not None:
        print(f"initial cost {ceres.initial_cost:.2f}, final cost {ceres.final_cost:.2f}")
        print(f"iterations {ceres.num_successful_steps + ceres.num_unsuccessful_steps} "
              f"({ceres.num_successful_steps} accepted), linear solver {ceres.linear_solver_type_used}, "
              f"termination {ceres.termination_type}, Ceres total {ceres.total_time_in_seconds:.3f} s")
    else:
        print(summary.brief_report())
    return 0


if __name__ == "__main__":
    sys.exit(main())
