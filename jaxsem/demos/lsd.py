"""LSD demo: one unseen building, one Inside-Outside trial, PRM + LSD against PRM + Unf.

A trained model is used when one is found: ``$JAXSEM_LSD_CHECKPOINT`` (a training workdir or an
exported .npz), else the shipped model ``jaxsem/lsd/pretrained.npz`` (see its MODEL_CARD.md); without
either, the demo makes a few expert samples on one train-family building and trains a small
network for a few steps first (it says so in the table): that model has seen very little, so
the comparison shows the pipeline rather than the thesis' result (benchmarks/lsd/lsd_table31.py).
The LSD sampler follows the thesis' rule (the window distribution, the window's minimum outside
it, -log p edge weights; no uniform mixing): the shipped network bounds its output range so that
the window's minimum keeps samples outside the window (``jaxsem.models.LSDConfig.log_range``).

Then the door step of thesis 5.8 (:mod:`jaxsem.demos.lsd_door`): in the same building, a door
that the shipped VoluMon door model found in one rendered view becomes the object map LSD plans
with, to a goal behind that door (figure ``lsd_door_demo.png``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import time

import jax

from ..lsd import (
    PRETRAINED,
    PRETRAINED_CPU,
    ExpertConfig,
    LSDSampler,
    full_map_distribution,
    generate_expert_samples,
    load_model,
    plot_navigation,
    tiny_config,
    train_and_evaluate,
)
from ..planning import NavConfig, generate_building, sample_tasks
from ..scripting import atomic_write_text, record_output
from .lsd_door import run_door_plan


def run(out_dir: pathlib.Path, quick: bool) -> str:
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    ckpt = os.environ.get("JAXSEM_LSD_CHECKPOINT")
    if ckpt:
        model, params, _, _ = load_model(ckpt)
        how = f"loaded trained model from {ckpt}"
    elif PRETRAINED.exists() or PRETRAINED_CPU.exists():
        model, params, _, _ = load_model()
        how = f"shipped model {(PRETRAINED if PRETRAINED.exists() else PRETRAINED_CPU).name}"
    else:
        b_train = generate_building(0, "train")
        n_samples = 8 if quick else 120
        data = generate_expert_samples(b_train, 0, ExpertConfig(samples_per_building=n_samples))
        cfg = (
            tiny_config()
            if quick
            else dataclasses.replace(
                tiny_config(),
                model=dataclasses.replace(tiny_config().model, features=(8, 16, 32, 32), context_features=32),
                stage1_steps=300,
                stage2_steps=150,
                batch_size=8,
                eval_every=150,
                checkpoint_every=150,
            )
        )
        res = train_and_evaluate(cfg, out_dir / "lsd_demo_model", data=data, progress=not quick)
        model, params = res.model, res.params
        how = (
            f"no checkpoint ($JAXSEM_LSD_CHECKPOINT unset): trained a small model on "
            f"{len(data['context'])} expert samples of one train building for "
            f"{cfg.stage1_steps}+{cfg.stage2_steps} steps (val NLL "
            f"{res.history[-1]['val_nll']:.2f} vs uniform {res.history[-1]['uniform_nll']:.2f})"
        )
    t_model = time.perf_counter() - t0

    building = generate_building(0, "test")
    task = sample_tasks(building, "IO", 1, seed=0)[0]
    cfg = NavConfig(n_samples=500, max_steps=150 if quick else 2000)
    key = jax.random.PRNGKey(0)
    sampler = LSDSampler(model, params, uniform_mix=0.0)
    results = {}
    for name, smp in (("uniform", None), ("lsd", sampler)):
        results[name] = task.navigate(building, key, cfg, smp)
    lsd = results["lsd"]
    xy = lsd.path[-1]
    dist = full_map_distribution(
        sampler,
        lsd.final_state,
        xy,
        task.goal,
        task.goal_outdoors,
        building,
    )
    fig = out_dir / "lsd_demo.png"
    plot_navigation(
        building,
        results,
        fig,
        task.start,
        task.goal,
        dist,
        title=f"test building 0, Inside-Outside task, N = {cfg.n_samples}",
    )
    record_output(fig)
    rows = {
        name: {
            "success": r.success,
            "reason": r.reason,
            "travelled_m": round(r.cost, 2),
            "cost_over_cstar": round(r.cost / task.c_star, 3),
            "steps": r.steps,
            "plans": r.plans,
        }
        for name, r in results.items()
    }

    door_lines, door = run_door_plan(out_dir, building, task, sampler, quick)
    atomic_write_text(
        out_dir / "lsd_demo.json",
        json.dumps(
            {
                "model": how,
                "c_star_m": task.c_star,
                "results": rows,
                "door": door,
                "seconds": time.perf_counter() - t0,
            },
            indent=1,
        ),
    )
    lines = [
        f"LSD demo ({how}; {t_model:.0f} s; thesis rule, no uniform mixing)",
        f"task: IO, start {task.start.round(1).tolist()} -> goal {task.goal.round(1).tolist()}, "
        f"C* = {task.c_star:.1f} m, step limit {cfg.max_steps}",
        f"{'planner':8s} {'success':>8s} {'reason':>10s} {'metres':>8s} {'C/C*':>6s} {'plans':>6s}",
    ]
    for name, r in rows.items():
        lines.append(
            f"{name:8s} {str(r['success']):>8s} {r['reason']:>10s} {r['travelled_m']:8.1f} "
            f"{r['cost_over_cstar']:6.2f} {r['plans']:6d}"
        )
    lines.append(f"figure: {fig}")
    lines += door_lines
    return "\n".join(lines)
