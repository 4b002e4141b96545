"""VoluMon training throughput: host-made batches (old) against batches made inside the jitted step (new).

Old: ``jaxsem.volumon.make_batch`` draws each sample's scene and noise with numpy on the host,
then renders in jit, then the train step runs (host work every step). New: the batch is drawn
and rendered from ``fold_in(key, step)`` inside the jitted train step (no host work, one
compilation). Same config (the ``fast`` preset unless ``--size``), same batch size; medians over
``--repeats`` steps after a warm-up step, each ended with ``block_until_ready``; data generation
alone is timed too.

    python benchmarks/volumon/volumon_data_speed.py
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import sys

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness


def _stepped_median(fn, repeats):
    """Median seconds of ``fn(step)`` over steps 1..repeats, after step 0 (the compile)."""
    steps = iter(range(repeats + 1))
    return _harness.median_time(lambda: fn(next(steps)), repeats=repeats)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--size", default="fast")
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path(__file__).resolve().parents[1] / "results")
    p.add_argument("--tag", default="volumon_data_speed")
    a = p.parse_args(argv)

    from jaxsem.volumon import get_config, make_batch, make_train_step
    from jaxsem.volumon._device_data import device_batch_jit, train_key  # layers: white-box
    from jaxsem.volumon._train import TRAIN_KEYS, augmentation_params, init_state  # layers: white-box

    base = get_config("both", a.size).replace(batch_size=a.batch_size)
    host_cfg = base.replace(data="host", num_train=100000)
    dev_cfg = base.replace(data="device")
    B, sc, S, pad = (
        a.batch_size,
        base.scene,
        base.model.input_size,
        base.model.global_padding,
    )

    def host_data(i):
        return make_batch(base.seed, np.arange(i * B, (i + 1) * B), sc, S, pad, "train")

    def dev_data(i):
        return device_batch_jit(jax.random.fold_in(train_key(base.seed), i), B, sc, S, pad)

    rows = {
        "data only: host (numpy draws + jitted render)": _stepped_median(host_data, a.repeats),
        "data only: device (jax.random + render, one jit)": _stepped_median(dev_data, a.repeats),
    }

    state, model, tx = init_state(host_cfg)
    step_h = make_train_step(model, tx, host_cfg)
    holder = {"s": state}

    def host_step(i):
        b = host_data(i)
        batch = {k: b[k] for k in TRAIN_KEYS}
        if host_cfg.augment:
            batch["aug"] = jax.tree.map(jax.numpy.asarray, augmentation_params(base.seed, i, B))
        holder["s"], terms = step_h(holder["s"], batch)
        return terms

    rows["train step: old (host data)"] = _stepped_median(host_step, a.repeats)
    state, model, tx = init_state(dev_cfg)
    step_d = make_train_step(model, tx, dev_cfg)
    holder = {"s": state}

    def dev_step(i):
        holder["s"], terms = step_d(holder["s"])
        return terms

    rows["train step: new (device data)"] = _stepped_median(dev_step, a.repeats)
    assert step_d._cache_size() == 1, "the device train step recompiled"
    old, new = (
        rows["train step: old (host data)"],
        rows["train step: new (device data)"],
    )
    dev = jax.devices()[0]
    machine = f"{os.cpu_count()}-core CPU (shared with other jobs)" if dev.platform == "cpu" else dev.device_kind
    record = {
        "command": "python " + " ".join([os.path.relpath(__file__)] + (sys.argv[1:] if argv is None else list(argv))),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine,
        "jax": jax.__version__,
        "size": a.size,
        "batch_size": B,
        "seconds": rows,
        "steps_per_s_old": 1 / old,
        "steps_per_s_new": 1 / new,
        "speedup": old / new,
    }
    a.out.mkdir(parents=True, exist_ok=True)
    tmp = a.out / f"{a.tag}.json.tmp"
    tmp.write_text(json.dumps(record, indent=1))
    tmp.replace(a.out / f"{a.tag}.json")
    lines = [
        "## VoluMon training throughput: host-made against device-made batches",
        "",
        f"Command: `{record['command']}`  ",
        f"Date: {record['date']}  ",
        f"Machine: {machine}, jax {jax.__version__}  ",
        f"Config: `{a.size}` preset, batch {B}; medians of {a.repeats} after a warm-up.",
        "",
        "| what | median s | steps/s |",
        "|---|---|---|",
    ]
    for k, v in rows.items():
        lines.append(f"| {k} | {v:.3f} | {1 / v:.2f} |")
    lines += [
        "",
        (
            f"New / old training throughput: {old / new:.2f}x ({1 / old:.2f} -> {1 / new:.2f} steps/s). "
            "No GPU was lent to this task, so only the CPU figures exist."
        ),
    ]
    tmp = a.out / f"{a.tag}.md.tmp"
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(a.out / f"{a.tag}.md")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
