"""Table 3.1 / figure 3-8: PRM + LSD vs PRM + Unf on unseen (test-family) buildings.

Inside-Inside (II) and Inside-Outside (IO) tasks, sample budgets N; success rate per N and, on
mutually successful trials, C_l/C*, C_b/C* (mean +- s.e.m.) and the zero-intercept slope of C_b on
C_l. Without --checkpoint it first generates expert data on train-family buildings and trains a
CPU-sized model (jaxsem.lsd.prepare_model). Writes benchmarks/results/lsd_table31.{json,md,png}.

    python benchmarks/lsd_table31.py                       # CPU-sized run (trains first)
    python benchmarks/lsd_table31.py --checkpoint runs/lsd --trials 20 --max-steps 10000
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import subprocess
import sys
import time

RESULTS = pathlib.Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--checkpoint", default=None, help="training workdir of a trained LSD model")
    p.add_argument("--workdir", default="runs/lsd_table31", help="where a model is trained if needed")
    p.add_argument("--train-buildings", type=int, default=6)
    p.add_argument("--samples-per-building", type=int, default=80)
    p.add_argument("--stage1-steps", type=int, default=600)
    p.add_argument("--stage2-steps", type=int, default=300)
    p.add_argument("--config", default="cpu", help="training config name (default | cpu | tiny)")
    p.add_argument("--test-buildings", type=int, default=2, help="test-family buildings")
    p.add_argument("--test-start", type=int, default=0, help="first test-family seed")
    p.add_argument("--trials", type=int, default=3, help="tasks per building and set")
    p.add_argument("--n", type=int, nargs="+", default=[100, 500, 1000, 5000], help="sample budgets N")
    p.add_argument("--sets", nargs="+", default=["II", "IO"])
    p.add_argument("--max-steps", type=int, default=1500, help="step limit per trial (thesis: 10000)")
    p.add_argument("--uniform-mix", type=float, default=0.1,
                   help="share of a uniform distribution mixed into the LSD window (0 = thesis rule)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=str(RESULTS), help="results folder")
    p.add_argument("--name", default="lsd_table31")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)

    import dataclasses

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.lsd import (ExperimentSetup, LSDSampler, format_table, get_config, plot_success,
                            prepare_model, run_trials, summarise)
    from jaxsem.planning import building_family

    enable_compilation_cache()
    t0 = time.perf_counter()
    cfg = dataclasses.replace(get_config(args.config), stage1_steps=args.stage1_steps,
                              stage2_steps=args.stage2_steps)
    setup = ExperimentSetup(args.train_buildings, args.samples_per_building)
    model, params, info = prepare_model(args.workdir, args.checkpoint, setup, cfg,
                                        progress=not args.no_progress)
    sampler = LSDSampler(model, params, uniform_mix=args.uniform_mix)
    buildings = building_family("test", args.test_buildings, start=args.test_start)
    records = run_trials(buildings, sampler, tuple(args.sets), tuple(args.n), args.trials, args.seed,
                         args.max_steps, progress=not args.no_progress)
    summary = summarise(records)
    table = format_table(summary)
    total = time.perf_counter() - t0
    print(table)

    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = "python benchmarks/lsd_table31.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip() or \
        datetime.datetime.now(datetime.timezone.utc).isoformat()
    at500 = {k: v for k, v in summary.items() if v["n"] == 500}
    (out / f"{args.name}.json").write_text(json.dumps(
        {"command": cmd, "date": date, "machine": "2-core CPU (shared, noisy)", "args": vars(args),
         "model": info, "summary": summary, "records": records, "seconds": total}, indent=1))
    plot_success(summary, out / f"{args.name}.png")
    behind = []
    for k, v in at500.items():
        ratio = v["success_lsd"] / v["success_uniform"] if v["success_uniform"] > 0 else float("inf")
        behind.append(f"{k}: LSD {100 * v['success_lsd']:.0f} % vs Unf {100 * v['success_uniform']:.0f} % "
                      f"(ratio {ratio:.2f}; goal >= 2)")
    md = [f"## LSD planner: Table 3.1 / figure 3-8 (`{args.name}`)", "",
          f"Command: `{cmd}`", "", f"Date: {date}", "", "Machine: 2-core CPU (shared, noisy)", "",
          f"Model: {json.dumps(info)}", "",
          f"Test buildings: {args.test_buildings} (test family), {args.trials} tasks per building and "
          f"set, step limit {args.max_steps}, seed {args.seed}, LSD uniform mix {args.uniform_mix}; "
          f"total {total / 60:.1f} min.", "",
          table, "",
          "Thesis (10 train / 3 test real floorplans, 1500 tasks): N=500 success Unf 25 % vs LSD 69 %; "
          "II C_l/C* 1.21-1.42 vs C_b/C* 1.32-1.51.", "",
          "Where we are behind: " + ("; ".join(behind) if behind else "N=500 not run") +
          f". This CPU-sized run has few trials (s.e.m. is large) and a small model trained on few "
          f"buildings (CPU-sized); the step limit is {args.max_steps}, not 10,000.", "",
          f"![success rates]({args.name}.png)", ""]
    (out / f"{args.name}.md").write_text("\n".join(md))
    print(f"wrote {out / (args.name + '.json')}, .md, .png in {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
