"""One-call pipeline for the house fine-tune of the LSD network (issue 25 item 4).

Generates expert shards (thesis 3.3.2) on the ``house`` building family mixed with the ``train``
family in parallel CPU worker processes until a deadline, then fine-tunes the shipped network on
them (``--config house``, on whatever accelerator JAX finds) until a second deadline, and exports
the final model, a compact copy of the last checkpoint and the learning curve:

    python train/lsd_house_gpu.py --root /tmp/lsdh --out OUT --house 180 --house-samples 160 \\
        --train 60 --train-samples 120 --workers 14 --data-deadline 200 --deadline 500

``--family campus`` swaps the house family for the long university buildings of the ``campus``
family (``--house`` then counts campus buildings; the model is ``lsd_campus.npz``). Several
families (``--family house campus``) draw ``--house`` buildings of each, taken in turn, for one
model of every kind of map (``lsd_mixed.npz``); start it from the model that already knows the
hardest family (``--init-from``).

Shards are named ``expert_<family>_<seed>.npz`` (as ``jaxsem lsd data`` writes them) and each is a
function of its family and seed, so a shorter run's shards are a prefix of a longer run's. Jobs
interleave the two families so that a run stopped at its deadline keeps the mix. Everything
under ``--root`` resumes; ``--out`` gets ``lsd_house.npz`` (the model), ``checkpoint.tar.gz`` (its last
checkpoints), ``curve.csv`` (the learning curve) and ``run.json``. ``--oracle`` also writes each
shard's full-map copy (``jaxsem.lsd.with_full_map``) and trains the fully supervised oracle
on it at the same time, same init, config and samples (``lsd_house_oracle.npz``,
``curve_oracle.csv``): the gap between the two is what the partial map costs.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import subprocess
import sys
import time

T0 = time.time()


def _worker_env() -> None:
    os.environ["JAX_PLATFORMS"] = "cpu"
    os.environ["XLA_FLAGS"] = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", "/tmp/jax_cache_lsdh")  # shared by respawned workers
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")


def _save(path: pathlib.Path, data: dict) -> None:
    from jaxsem.scripting import atomic_save_npz

    atomic_save_npz(path, record=False, **data)  # a killed worker leaves no half shard


def _job(args):
    family, seed, samples, out, out_full = args
    from jaxsem import lsd, planning

    path = pathlib.Path(out) / f"expert_{family}_{seed:05d}.npz"
    if path.exists():
        return str(path), -1
    b = planning.generate_building(seed, family)
    data = lsd.generate_expert_samples(b, seed, lsd.ExpertConfig(samples_per_building=samples))
    if out_full:  # the oracle's copy first: a shard in `out` always has its full-map twin
        _save(pathlib.Path(out_full) / path.name, lsd.with_full_map(data, b))
    _save(path, data)
    return str(path), int(len(data["context"]))


def job_list(args, out: str, full: str) -> list[tuple]:
    """The shard jobs in the order they run: ``ratio`` buildings of the new families in turn, then
    one train building, so that a run stopped at its data deadline keeps the mix."""
    house = [(f, s, args.house_samples, out, full) for s in range(args.house) for f in args.family]
    train = [("train", s, args.train_samples, out, full) for s in range(args.train)]
    jobs, ratio = [], max(1, round(len(house) / max(1, len(train))))
    while house or train:
        jobs += house[:ratio] + train[:1]
        house, train = house[ratio:], train[1:]
    return jobs


def make_data(args, data_dir: pathlib.Path, full_dir: pathlib.Path | None) -> dict:
    import multiprocessing as mp

    data_dir.mkdir(parents=True, exist_ok=True)
    if full_dir is not None:
        full_dir.mkdir(parents=True, exist_ok=True)
    full = str(full_dir) if full_dir is not None else ""
    jobs = job_list(args, str(data_dir), full)
    done, t = [], time.time()
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.workers, initializer=_worker_env, maxtasksperchild=16) as pool:
        it = pool.imap_unordered(_job, jobs)
        while True:
            left = args.data_deadline - (time.time() - T0)
            if left <= 0:
                print(f"data: deadline reached after {len(done)} of {len(jobs)} shards", flush=True)
                pool.terminate()
                break
            try:
                done.append(it.next(timeout=left))
            except StopIteration:
                break
            except mp.TimeoutError:
                continue
    for d in (data_dir, full_dir):  # temporary files of workers stopped at the deadline
        for p in d.glob(".expert_*.tmp") if d is not None else ():
            p.unlink()
    shards = sorted(str(p) for p in data_dir.glob("expert_*.npz"))
    fam = {f: sum(1 for s in shards if f"expert_{f}_" in s) for f in (*args.family, "train")}
    info = {"shards": len(shards), "by_family": fam, "seconds": round(time.time() - t, 1), "jobs": len(jobs)}
    print("data:", info, flush=True)
    return info


def _model_name(families: list[str]) -> str:
    """The exported model's name: the one new family's, or ``mixed`` for several."""
    return families[0] if len(set(families)) == 1 else "mixed"


def _check(ap: argparse.ArgumentParser, args) -> None:
    """Every flag checked before the data phase (minutes of CPU work that a bad ``--init-from`` or
    ``--set`` would otherwise waste before the trainer refuses it): ``ap.error`` (exit 2, one
    line naming the flag) on the first bad one."""
    for flag, value, low in (
        ("--workers", args.workers, 1),
        ("--house", args.house, 0),
        ("--train", args.train, 0),
        ("--house-samples", args.house_samples, 1),
        ("--train-samples", args.train_samples, 1),
    ):
        if value < low:
            ap.error(f"{flag}: expected a whole number >= {low}, got {value}")
    if len(set(args.family)) != len(args.family):
        ap.error(f"--family: each family once, got {' '.join(args.family)}")
    if not 0 < args.data_deadline < args.deadline < math.inf:
        ap.error(
            f"--data-deadline, --deadline: expected 0 < --data-deadline < --deadline (finite seconds), "
            f"got {args.data_deadline} and {args.deadline}"
        )
    if not pathlib.Path(args.init_from).is_file():
        ap.error(f"--init-from: no such model file {args.init_from!r}")
    for item in args.set:
        if "=" not in item or not item.split("=", 1)[0].strip():
            ap.error(f"--set: expected name=value, got {item!r}")
    for flag, value in (("--root", args.root), ("--out", args.out)):
        if pathlib.Path(value).exists() and not pathlib.Path(value).is_dir():
            ap.error(f"{flag}: {value} exists and is not a folder")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", required=True, help="data and workdir (resumes)")
    ap.add_argument("--out", required=True, help="where the model, checkpoint and curve go")
    ap.add_argument(
        "--family", nargs="+", default=["house"], choices=("house", "campus"), help="the new building families"
    )
    ap.add_argument("--house", type=int, default=180, help="buildings of each --family")
    ap.add_argument("--house-samples", type=int, default=160, help="expert samples per --family building")
    ap.add_argument("--train", type=int, default=60)
    ap.add_argument("--train-samples", type=int, default=120)
    ap.add_argument("--workers", type=int, default=14)
    ap.add_argument("--data-deadline", type=float, default=200.0, help="seconds after start")
    ap.add_argument("--deadline", type=float, default=500.0, help="seconds after start: training stops")
    ap.add_argument(
        "--init-from",
        default=str(pathlib.Path(__file__).resolve().parents[1] / "jaxsem/lsd/pretrained_generated.npz"),
        help="the weights the fine-tunes start from (default: the generated-building model, as every shipped fine-tune)",
    )
    ap.add_argument("--oracle", action="store_true", help="also train the full-map oracle beside it")
    ap.add_argument("--set", action="append", default=[], help="extra TrainConfig overrides (name=value)")
    args = ap.parse_args(argv)
    _check(ap, args)
    # absolute: the trainers run with `root` as their working directory (below)
    root, out = pathlib.Path(args.root).resolve(), pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    data_info = make_data(args, root / "data", root / "data_full" if args.oracle else None)

    runs = {"house": (root / "data", root / "work")}
    if args.oracle:  # the fully supervised oracle: same init, config and samples, true-map crops
        runs["oracle"] = (root / "data_full", root / "work_full")
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_PLATFORMS", "XLA_FLAGS", "OMP_NUM_THREADS")}
    # the trainers run in `root` (below): this checkout first, the rest of PYTHONPATH made absolute
    paths = [str(pathlib.Path(__file__).resolve().parents[1])]
    paths += [str(pathlib.Path(x).resolve()) for x in env.get("PYTHONPATH", "").split(os.pathsep) if x]
    env["PYTHONPATH"] = os.pathsep.join(paths)
    if len(runs) > 1:
        env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = "0.4"
    procs, t = {}, time.time()
    for name, (data, workdir) in runs.items():
        cmd = [sys.executable, "-m", "jaxsem.cli", "lsd", "train", "--data", str(data), "--workdir", str(workdir)]
        cmd += ["--config", "house", "--set", f"init_from={args.init_from}", "--run-dir", str(root / f"run_{name}")]
        for s in args.set:
            cmd += ["--set", s]
        print(f"train {name}:", " ".join(cmd), flush=True)
        # cwd: `python -m` puts the working directory first on sys.path, ahead of PYTHONPATH
        procs[name] = subprocess.Popen(cmd, env=env, cwd=str(root))
    rcs = {}
    for name, proc in procs.items():
        try:
            rcs[name] = proc.wait(timeout=max(10.0, args.deadline - (time.time() - T0)))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            rcs[name] = "timeout"
    train_s = time.time() - t
    print(f"train: rc {rcs}, {train_s:.0f} s", flush=True)

    # Exported on the platform that trained: orbax refuses to restore a GPU checkpoint on the CPU
    # ("Topology mismatch").
    from jaxsem import lsd

    info = {"train_rc": rcs, "train_seconds": round(train_s, 1), "data": data_info}
    for name, (_, workdir) in runs.items():
        suffix = "" if name == "house" else "_oracle"
        try:
            _, params, config = lsd.load_trained(workdir)
            lsd.export_model(out / f"lsd_{_model_name(args.family)}{suffix}.npz", config, params)
            rows = [json.loads(x) for x in (workdir / "metrics.jsonl").read_text().splitlines() if x.strip()]
        except Exception as e:  # report and go on: the other run's files still come back
            print(f"export {name}: {e!r}", flush=True)
            continue
        lines = ["step,stage,train_nll,val_nll,uniform_nll"]
        lines += [
            f"{r['step']},{r['stage']},{r['train_nll']:.4f},{r['val_nll']:.4f},{r['uniform_nll']:.4f}" for r in rows
        ]
        (out / f"curve{suffix}.csv").write_text("\n".join(lines) + "\n")
        info[f"last_step_{name}"] = max((r["step"] for r in rows), default=0)
        if name == "house":
            extra = ["config.json"] if (workdir / "config.json").exists() else []
            tar = ["tar", "czf", str(out / "checkpoint.tar.gz"), "-C", str(workdir), "checkpoints", *extra]
            subprocess.run(tar, check=False)
    info["total_seconds"] = round(time.time() - T0, 1)
    (out / "run.json").write_text(json.dumps(info, indent=1))
    print("done:", info, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
