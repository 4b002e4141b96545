"""Table 3.1 / figure 3-8: PRM + LSD vs PRM + Unf on unseen (test-family) buildings.

Inside-Inside (II) and Inside-Outside (IO) tasks, sample budgets N; success rate per N (with
binomial standard errors and the paired count of LSD-only / uniform-only successes) and, on
mutually successful trials, C_l/C*, C_b/C* (mean +- s.e.m.) and the zero-intercept slope of C_b on
C_l. The model is the shipped one (``jaxsem.lsd.load_model()``) unless --checkpoint names another
or --train trains a CPU-sized one first. LSD uses the thesis' rule by default (--uniform-mix 0:
the window distribution, the window's minimum outside it, -log p edge weights). --ablations adds
planners on the same tasks: 'mix10' (10 % uniform mixed into the window), 'euclid' (LSD samples,
Euclidean edge weights), 'nogrow' (both planners with the thesis' end-of-trial on the first failed
roadmap), 'growuni' (LSD whose failed roadmaps grow with uniform samples, NavConfig.growth),
'outmass' (LSD with a calibrated mass outside the window, NavConfig.outside_mass); 'nogrow'
with 'outmass' adds the two together; 'thesis' (both planners under the thesis' protocol of
section 3.3.3 as written: a fresh roadmap of N samples at every replan, the uniform one too, and
the first roadmap without a path ends the trial: NavConfig.reuse_roadmap=False, max_growth=0).
--other MODEL runs a second LSD model on the same tasks beside the first (rows 'lsd_other' and,
with 'thesis', 'lsd_other_thesis'), paired with it task by task (which model to ship).
--only-ablations runs just the ablation planners (merge with a run of the same tasks:
--merge A.json B.json joins records of the same task planner-wise). --devices N|all deals the
trials over devices (jaxsem.lsd.run_trials(mesh=...)). Writes <out>/<name>.{json,md,png}.

    python benchmarks/lsd/lsd_table31.py --test-buildings 10 --trials 10 --n 500 --sets II IO \\
        --uniform-mix 0 --seed 1 --out benchmarks/results --name lsd_table31 --no-progress
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib
import subprocess
import sys
import time

RESULTS = pathlib.Path(__file__).resolve().parents[1] / "results"
ABLATIONS = ("mix10", "euclid", "nogrow", "growuni", "outmass", "thesis")
# 'outmass': the cells outside the LSD window share a calibrated mass instead of the window's
# minimum: the mean share of the expert's optimal path that lies outside the 16 m window, on
# train-family buildings 0-19 (benchmarks/lsd/lsd_outside_share.py, 2472 samples): 0.511 for an
# indoor goal, 0.642 for an outdoor one (NavConfig.outside_mass).
OUTSIDE_MASS = (0.511, 0.642)
MACHINE = "2-core CPU (shared, noisy)"


def _write(path: pathlib.Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _check(args) -> None:
    for kind in args.sets:
        if kind not in ("II", "IO"):
            raise SystemExit(f"--sets: expected II and/or IO, got {kind!r}")
    for name in ("test_buildings", "trials", "max_steps"):
        if getattr(args, name) < 1:
            raise SystemExit(f"--{name.replace('_', '-')}: expected >= 1, got {getattr(args, name)}")
    if min(args.n) < 1:
        raise SystemExit(f"--n: expected positive sample budgets, got {args.n}")
    if not 0.0 <= args.uniform_mix < 1.0:
        raise SystemExit(f"--uniform-mix: expected in [0, 1), got {args.uniform_mix}")
    if args.family not in ("test", "train"):
        raise SystemExit(f"--family: expected test or train, got {args.family!r}")
    if args.only_ablations and not args.ablations:
        raise SystemExit("--only-ablations: needs --ablations")
    for a in args.ablations:
        if a not in ABLATIONS:
            raise SystemExit(f"--ablations: expected some of {', '.join(ABLATIONS)}, got {a!r}")
    if args.checkpoint and not pathlib.Path(args.checkpoint).exists():
        raise SystemExit(f"--checkpoint: no such file or folder {args.checkpoint!r}")
    if args.other is not None:
        check_model("--other", args.other)


def check_model(flag: str, source: str, prog: str = "") -> None:
    """An LSD model flag (exported .npz, workdir or shipped name) loads, or SystemExit naming
    ``flag`` (``prog``: the script's name in front, as lsd_real.py words its errors)."""
    from jaxsem.lsd import load_model

    try:
        load_model(source)
    except ValueError as exc:
        raise SystemExit(f"{prog}{flag}: {exc}") from None


def _mesh(devices):
    """The device mesh of --devices (None without it); SystemExit naming --devices if unusable."""
    if devices is None:
        return None
    from jaxsem import parallel

    parallel.initialize_distributed()  # a no-op on one machine
    try:
        return parallel.devices_mesh(devices)
    except ValueError as exc:
        raise SystemExit(f"--devices: {str(exc).removeprefix('devices: ')}") from None


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument(
        "--checkpoint",
        default=None,
        help="LSD training workdir or exported .npz (None: the shipped model)",
    )
    p.add_argument(
        "--other",
        default=None,
        metavar="MODEL",
        help="a second LSD model (exported .npz or a shipped name) on the same tasks, paired with the first",
    )
    p.add_argument(
        "--train",
        action="store_true",
        help="train a CPU-sized model in --workdir first",
    )
    p.add_argument("--workdir", default="runs/lsd_table31", help="where --train trains")
    p.add_argument("--train-buildings", type=int, default=6, help="with --train")
    p.add_argument("--samples-per-building", type=int, default=80, help="with --train")
    p.add_argument("--stage1-steps", type=int, default=600, help="with --train")
    p.add_argument("--stage2-steps", type=int, default=300, help="with --train")
    p.add_argument(
        "--config",
        default="cpu",
        help="training config name with --train (default | cpu | tiny)",
    )
    p.add_argument("--test-buildings", type=int, default=2, help="test-family buildings")
    p.add_argument("--test-start", type=int, default=0, help="first test-family seed")
    p.add_argument("--trials", type=int, default=3, help="tasks per building and set")
    p.add_argument(
        "--n",
        type=int,
        nargs="+",
        default=[100, 500, 1000, 5000],
        help="sample budgets N",
    )
    p.add_argument("--sets", nargs="+", default=["II", "IO"], help="II and/or IO")
    p.add_argument(
        "--max-steps",
        type=int,
        default=1500,
        help="step limit per trial (thesis: 10000)",
    )
    p.add_argument(
        "--uniform-mix",
        type=float,
        default=0.0,
        help="share of a uniform distribution mixed into the LSD window (0 = thesis rule)",
    )
    p.add_argument(
        "--ablations",
        nargs="*",
        default=[],
        help=f"extra planners: {' '.join(ABLATIONS)}",
    )
    p.add_argument("--seed", type=int, default=0, help="task and sampling seed")
    p.add_argument(
        "--only-ablations",
        action="store_true",
        help="run only the --ablations planners (records to --merge with a full run of the same tasks)",
    )
    p.add_argument(
        "--family",
        default="test",
        help="building family of the trials: test (held out) or train (for pilots that must not touch test seeds)",
    )
    p.add_argument(
        "--devices",
        default=None,
        help="run the trials over N devices or 'all' (jaxsem.lsd.run_trials(mesh=...): trial "
        "groups, one host thread per device; same records as one device); default: one device",
    )
    p.add_argument("--out", default=str(RESULTS), help="results folder")
    p.add_argument("--name", default="lsd_table31", help="result file stem")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
    p.add_argument(
        "--merge",
        nargs="+",
        default=None,
        metavar="JSON",
        help="instead of running: merge the records of earlier result files into <out>/<name>",
    )
    args = p.parse_args(argv)
    if args.merge:
        return _merge(args, argv)
    _check(args)
    try:
        return _run(args, argv)
    except (ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"lsd_table31: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2


def _merge(args, argv) -> int:
    from jaxsem.lsd import summarise
    from jaxsem.lsd._experiment import format_table, merge_records  # layers: white-box

    runs, parts = [], []
    for f in args.merge:
        try:
            d = json.loads(pathlib.Path(f).read_text())
        except (OSError, ValueError) as exc:
            raise SystemExit(f"--merge: cannot read {f!r} ({type(exc).__name__})") from None
        if "records" not in d:
            raise SystemExit(f"--merge: {f!r} has no 'records' (not a lsd_table31 result)")
        runs.append(d["records"])
        parts.append(
            {
                "file": str(f),
                "command": d.get("command"),
                "date": d.get("date"),
                "seconds": d.get("seconds"),
                "model": d.get("model"),
            }
        )
    records = merge_records(*runs)
    if any("uniform" not in r or "lsd" not in r for r in records):
        raise SystemExit(
            "--merge: some tasks have no 'uniform' / 'lsd' result (an --only-ablations run needs its full run)"
        )
    summary = summarise(records)
    table = format_table(summary)
    print(table)
    model = parts[0]["model"] if parts else None
    md = [
        f"Model: {json.dumps(model)}",
        "",
        "Parts (each a run of this script; buildings and tasks as in its command; records of the "
        "same task joined planner-wise):",
        "",
        *[f"- `{q['command']}` ({q['date']}, {(q['seconds'] or 0) / 60:.1f} min)" for q in parts],
        "",
        *_md_tail(table, "Success", summary, args.name),
    ]
    record = {"parts": parts, "model": model, "summary": summary, "records": records}
    out = _write_results(args, argv, record, md, command_label="Merged by")
    print(f"wrote {out / (args.name + '.json')}, .md, .png")
    return 0


def _md_tail(table: str, label: str, summary: dict, name: str) -> list:
    """The results markdown's last lines: the table, the success verdict of every row (``label``
    leads it), the thesis' figures and the success plot."""
    verdict = [
        f"{k}: LSD {100 * v['success_lsd']:.0f} +- {100 * v['success_lsd_sem']:.0f} % vs Unf "
        f"{100 * v['success_uniform']:.0f} +- {100 * v['success_uniform_sem']:.0f} % "
        f"({100 * (v['success_lsd'] - v['success_uniform']):+.0f} points; target >= +15), "
        f"{v['lsd_only']} LSD-only vs {v['uniform_only']} uniform-only successes"
        for k, v in summary.items()
    ]
    return [
        table,
        "",
        f"{label} (binomial s.e.m.): " + "; ".join(verdict) + ".",
        "",
        "Thesis (10 train / 3 test real floorplans, 1500 tasks): N=500 success Unf 25 % vs LSD 69 %; "
        "II C_l/C* 1.21-1.42 vs C_b/C* 1.32-1.51.",
        "",
        f"![success rates]({name}.png)",
        "",
    ]


def _write_results(args, argv, record: dict, md: list | None, command_label: str = "Command") -> pathlib.Path:
    """Writes ``<out>/<name>.json``: the command line, the date and the machine, then ``record``;
    with ``md`` (the markdown's body) also the success plot of ``record["summary"]`` and
    ``<out>/<name>.md``: the title, the command (led by ``command_label``), the date and the machine,
    then ``md``. Returns the output folder (created)."""
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    cmd = "python benchmarks/lsd/lsd_table31.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = (
        subprocess.run(["date", "-u"], capture_output=True, text=True, check=False).stdout.strip()
        or datetime.datetime.now(datetime.timezone.utc).isoformat()
    )
    _write(
        out / f"{args.name}.json", json.dumps({"command": cmd, "date": date, "machine": MACHINE, **record}, indent=1)
    )
    if md is not None:
        from jaxsem.lsd import plot_success

        plot_success(record["summary"], out / f"{args.name}.png")
        title = f"## LSD planner: Table 3.1 / figure 3-8 (`{args.name}`)"
        head = [title, "", f"{command_label}: `{cmd}`", "", f"Date: {date}", "", f"Machine: {MACHINE}", ""]
        _write(out / f"{args.name}.md", "\n".join(head + md))
    return out


def _write_partial(args, argv, records, info, total) -> int:
    """An --only-ablations run: records only (no summary without 'uniform' and 'lsd')."""
    record = {"args": vars(args), "model": info, "summary": {}, "records": records, "seconds": total}
    out = _write_results(args, argv, record, None)
    names = sorted({k for r in records for k, v in r.items() if isinstance(v, dict)})
    for name in names:
        for kind in args.sets:
            x = [r[name]["success"] for r in records if r["set"] == kind]
            print(f"{name} {kind}: {sum(x)} / {len(x)} successes")
    a, b = "lsd_other_thesis", "lsd_thesis"  # --other beside the first model, task by task
    if a in names and b in names:
        for kind in args.sets:
            rs = [r for r in records if r["set"] == kind]
            only_a = sum(r[a]["success"] and not r[b]["success"] for r in rs)
            only_b = sum(r[b]["success"] and not r[a]["success"] for r in rs)
            print(f"{a} vs {b} {kind}: {only_a} / {only_b} tasks only one solved, of {len(rs)}")
    print(f"wrote {out / (args.name + '.json')} (records only: --merge it with a full run) in {total / 60:.1f} min")
    return 0


def _run(args, argv) -> int:
    import dataclasses

    from jaxsem.cli import enable_compilation_cache
    from jaxsem.lsd import LSDSampler, get_config, load_model, run_trials, summarise
    from jaxsem.lsd._experiment import ExperimentSetup, format_table, prepare_model  # layers: white-box
    from jaxsem.planning._buildings import building_family  # layers: white-box

    enable_compilation_cache()
    mesh = _mesh(args.devices)
    t0 = time.perf_counter()
    if args.train:
        cfg = dataclasses.replace(
            get_config(args.config),
            stage1_steps=args.stage1_steps,
            stage2_steps=args.stage2_steps,
        )
        setup = ExperimentSetup(args.train_buildings, args.samples_per_building)
        model, params, info = prepare_model(args.workdir, args.checkpoint, setup, cfg, progress=not args.no_progress)
    else:
        model, params, mcfg, _ = load_model(args.checkpoint)
        info = {
            "checkpoint": args.checkpoint or "shipped (jaxsem.lsd.PRETRAINED)",
            "trained_here": False,
            "model": dataclasses.asdict(mcfg.model),
        }
    sampler = LSDSampler(model, params, uniform_mix=args.uniform_mix)
    variants = {}
    if "mix10" in args.ablations:
        variants["lsd_mix10"] = (LSDSampler(model, params, uniform_mix=0.1), {})
    if "euclid" in args.ablations:
        variants["lsd_euclid"] = (sampler, {"edge_weight": "euclidean"})
    if "growuni" in args.ablations:
        variants["lsd_growuni"] = (sampler, {"growth": "uniform"})
    if "outmass" in args.ablations:
        variants["lsd_outmass"] = (sampler, {"outside_mass": OUTSIDE_MASS})
    if "nogrow" in args.ablations:
        variants["uniform_nogrow"] = (None, {"max_growth": 0})
        variants["lsd_nogrow"] = (sampler, {"max_growth": 0})
        if "outmass" in args.ablations:  # both variants at once: the calibrated fill, thesis' end-of-trial
            variants["lsd_outmass_nogrow"] = (sampler, {"outside_mass": OUTSIDE_MASS, "max_growth": 0})
    if "thesis" in args.ablations:  # LSD never reuses a roadmap: its thesis row is nogrow
        variants["uniform_thesis"] = (None, {"max_growth": 0, "reuse_roadmap": False})
        variants["lsd_thesis"] = (sampler, {"max_growth": 0})
    if args.other is not None:
        other, other_params, _, _ = load_model(args.other)
        other_sampler = LSDSampler(other, other_params, uniform_mix=args.uniform_mix)
        if not args.only_ablations:
            variants["lsd_other"] = (other_sampler, {})
        if "thesis" in args.ablations:
            variants["lsd_other_thesis"] = (other_sampler, {"max_growth": 0})
    buildings = building_family(args.family, args.test_buildings, start=args.test_start)
    records = run_trials(
        buildings,
        sampler,
        tuple(args.sets),
        tuple(args.n),
        args.trials,
        args.seed,
        args.max_steps,
        progress=not args.no_progress,
        variants=variants,
        mesh=mesh,
        base=not args.only_ablations,
    )
    if args.only_ablations:
        return _write_partial(args, argv, records, info, time.perf_counter() - t0)
    summary = summarise(records)
    table = format_table(summary)
    total = time.perf_counter() - t0
    devices = "1 (default device)" if mesh is None else f"{mesh.size} ({mesh.devices.flat[0].platform})"
    print(table)
    md = [
        f"Model: {json.dumps(info)}",
        "",
        f"Test buildings: {args.test_buildings} ({args.family} family, seeds {args.test_start}.."
        f"{args.test_start + args.test_buildings - 1}), {args.trials} tasks per building and set, step limit "
        f"{args.max_steps}, seed {args.seed}, LSD uniform mix {args.uniform_mix}; a failed roadmap is grown "
        f"up to twice (NavConfig.max_growth); devices {devices}; total {total / 60:.1f} min.",
        "",
        *_md_tail(table, "Success at each N", summary, args.name),
    ]
    record = {"args": vars(args), "model": info, "summary": summary, "records": records, "seconds": total}
    out = _write_results(args, argv, record, md)
    print(f"wrote {out / (args.name + '.json')}, .md, .png in {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
