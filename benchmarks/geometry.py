"""Benchmark: `project_bbox` over a million (ellipsoid, camera) pairs, float32, jitted, against the
straightforward numpy formulation (batched matmuls Q* = Z D Z^T, C* = P Q* P^T, then eq. 4.10) in
the same run; plus the gradient of a box loss w.r.t. every input (with jaxsem's custom JVP rule and,
for comparison, plain autodiff of the same forward formulas), compile times, and the float32 error
against a float64 evaluation of the same pairs.

    python benchmarks/geometry.py [--pairs 1000000] [--repeats 9] [--study]

``--study`` adds a second table measured in subprocesses: the same run pinned to one core
(``taskset -c 0``), with XLA:CPU's legacy loop emitter (``--xla_cpu_use_fusion_emitters=false``),
and with the inputs stored component-major (transposed inside the jitted function).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import shutil
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxsem import quadrics as q

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _harness

RESULTS = pathlib.Path(__file__).parent / "results"


def make_pairs(n, seed=0):
    rng = np.random.default_rng(seed)
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(seed), (n,), dtype=jnp.float32))
    radii = rng.uniform(0.1, 3.0, (n, 3)).astype(np.float32)
    cam_R = np.asarray(q.random_rotation(jax.random.PRNGKey(seed + 1), (n,), dtype=jnp.float32))
    cam_t = rng.normal(scale=5.0, size=(n, 3)).astype(np.float32)
    depth = rng.uniform(2, 20, n) + radii.max(1)
    center_cam = np.column_stack([rng.uniform(-0.4, 0.4, (n, 2)) * depth[:, None], depth])
    center = np.einsum("nji,nj->ni", cam_R, center_cam - cam_t).astype(np.float32)
    pose = np.zeros((n, 4, 4), np.float32)
    pose[:, :3, :3], pose[:, :3, 3], pose[:, 3, 3] = cam_R, cam_t, 1
    f = rng.uniform(300, 1200, n)
    K = np.zeros((n, 3, 3), np.float32)
    K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = f, f, 320, 240, 1
    return R, center, radii, K, pose


def numpy_project_bbox(R, c, r, K, pose):
    """The textbook formulation: build Q* and P as matrices, multiply, read eq. 4.10."""
    n = R.shape[0]
    Z = np.zeros((n, 4, 4), R.dtype)
    Z[:, :3, :3], Z[:, :3, 3], Z[:, 3, 3] = R, c, 1
    D = np.zeros((n, 4, 4), R.dtype)
    D[:, 0, 0], D[:, 1, 1], D[:, 2, 2], D[:, 3, 3] = r[:, 0] ** 2, r[:, 1] ** 2, r[:, 2] ** 2, -1
    Qs = Z @ D @ np.swapaxes(Z, 1, 2)
    P = K @ pose[:, :3, :]
    C = P @ Qs @ np.swapaxes(P, 1, 2)
    c11, c13, c22, c23, c33 = C[:, 0, 0], C[:, 0, 2], C[:, 1, 1], C[:, 1, 2], C[:, 2, 2]
    su = np.sqrt(np.maximum(c13**2 - c11 * c33, 0))
    sv = np.sqrt(np.maximum(c23**2 - c22 * c33, 0))
    return np.stack([(c13 + su) / c33, (c23 + sv) / c33, (c13 - su) / c33, (c23 - sv) / c33], 1)


def box_loss(project):
    def loss(R, c, r, K, pose, target):
        box, valid = project(R, c, r, K, pose)
        return jnp.sum(jnp.where(valid[:, None], jnp.square(box - target), 0.0))

    return loss


def measure(n, repeats, with_numpy=True, layout="batch-leading"):
    host = make_pairs(n)
    dev = [jnp.asarray(a) for a in host]
    scale = 1e6 / n  # report per million pairs
    if layout == "component-major":
        # Stored with the batch axis last; the jitted function moves it to the front, which XLA
        # turns into a layout change of its loops' reads instead of a copy.
        dev = [jnp.moveaxis(a, 0, -1) for a in dev]
        to_front = lambda args: [jnp.moveaxis(a, -1, 0) for a in args]
    else:
        to_front = lambda args: list(args)
    project_fn = lambda *a: q.project_bbox(*to_front(a))

    t0 = time.perf_counter()
    project = jax.jit(project_fn).lower(*dev).compile()
    compile_fwd = time.perf_counter() - t0
    box, valid = jax.block_until_ready(project(*dev))
    target = box + 1.0

    grad_fn = jax.grad(lambda *a: box_loss(q.project_bbox)(*to_front(a[:5]), a[5]), argnums=(0, 1, 2, 3, 4))
    t0 = time.perf_counter()
    grad = jax.jit(grad_fn).lower(*dev, target).compile()
    compile_grad = time.perf_counter() - t0
    jax.block_until_ready(grad(*dev, target))

    fns = {"fwd": lambda: project(*dev), "grad": lambda: grad(*dev, target)}
    rounds = {"fwd": repeats, "grad": repeats}
    if layout == "batch-leading":
        # Plain autodiff of the same forward formulas (no custom JVP rule), for comparison.
        plain = jax.jit(jax.grad(box_loss(q.project_bbox_reference), argnums=(0, 1, 2, 3, 4)))
        plain = plain.lower(*dev, target).compile()
        jax.block_until_ready(plain(*dev, target))
        fns["grad_plain"], rounds["grad_plain"] = (lambda: plain(*dev, target)), max(1, min(5, repeats))
    if with_numpy:
        fns["numpy"], rounds["numpy"] = (lambda: numpy_project_bbox(*host)), max(1, min(3, repeats))
    med = _harness.interleaved_medians(fns, rounds)
    out = {
        "pairs": n,
        "jax_project_bbox_ms_per_million": 1e3 * med["fwd"] * scale,
        "grad_all_inputs_ms_per_million": 1e3 * med["grad"] * scale,
        "compile_forward_s": compile_fwd,
        "compile_grad_s": compile_grad,
        "valid_fraction": float(np.mean(np.asarray(valid))),
    }
    if "grad_plain" in med:
        out["grad_plain_autodiff_ms_per_million"] = 1e3 * med["grad_plain"] * scale
    if with_numpy:
        box_np = numpy_project_bbox(*host)
        ref = numpy_project_bbox(*[a.astype(np.float64) for a in host])  # float64, same formulas
        ok = np.asarray(valid)
        err = lambda b: float(np.max(np.abs(np.asarray(b, np.float64) - ref)[ok]))
        out.update(
            {
                "numpy_matrix_formulation_ms_per_million": 1e3 * med["numpy"] * scale,
                "speedup_vs_numpy": med["numpy"] / med["fwd"],
                "max_abs_diff_px_vs_numpy": float(np.max(np.abs(np.asarray(box, np.float64) - box_np)[ok])),
                "max_abs_err_px_jax_float32_vs_float64": err(box),
                "max_abs_err_px_numpy_float32_vs_float64": err(box_np),
            }
        )
    return out


def study(n, repeats):
    """Re-runs this script's measurement in subprocesses under other settings."""
    settings = [
        ("pinned to one core (`taskset -c 0`)", ["taskset", "-c", "0"], {}, "batch-leading"),
        (
            "XLA:CPU legacy loop emitter (`--xla_cpu_use_fusion_emitters=false`)",
            [],
            {"XLA_FLAGS": "--xla_cpu_use_fusion_emitters=false"},
            "batch-leading",
        ),
        ("inputs stored component-major (batch axis last)", [], {}, "component-major"),
        ("reference (same settings as the main table)", [], {}, "batch-leading"),
    ]
    rows = []
    for label, prefix, env, layout in settings:
        if prefix and shutil.which(prefix[0]) is None:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            path = pathlib.Path(tmp) / "out.json"
            cmd = prefix + [
                sys.executable,
                __file__,
                "--pairs",
                str(n),
                "--repeats",
                str(repeats),
                "--layout",
                layout,
                "--measure-only",
                str(path),
            ]
            subprocess.run(cmd, check=True, env={**os.environ, **env})
            rows.append((label, json.loads(path.read_text())))
    return rows


def notes(r):
    """The prose under the tables: targets, where we are behind, and what the numbers mean."""
    fwd, speedup = r["jax_project_bbox_ms_per_million"], r["speedup_vs_numpy"]
    grad, plain = r["grad_all_inputs_ms_per_million"], r["grad_plain_autodiff_ms_per_million"]
    met = lambda ok: "met" if ok else "**not met**"
    lines = [
        f"Targets (issue 2): at least 10x the numpy formulation in the same run: {met(speedup >= 10)} "
        f"({speedup:.1f}x); under 40 ms per million pairs: {met(fwd < 40)} ({fwd:.1f} ms). Reading the "
        "inputs alone (160 bytes per pair: R, c, r, K and the 4x4 pose in float32) bounds the forward "
        "from below at roughly 15 ms per million here.",
        "",
        "How: `project_bbox` runs a fused private path (`jaxsem/_geometry/bbox.py`, behind the jaxsem.quadrics facade) "
        "that agrees with `conic_bbox(project_dual_conic(dual_quadric(...)))` to "
        "~1e-12 relative in float64, masks and gradients included (`tests/geometry/test_quadrics.py`). The "
        "forward is two elementwise XLA loops over the inputs: the validity mask, and the four edges "
        "computed in a (..., 4) lane space (one lane per edge, so the loop vectorises across lanes "
        "and reads each input once). The gradient comes from a custom JVP rule whose transpose keeps "
        "one (..., 2, 9) cotangent in memory and is otherwise elementwise in each input's own shape; "
        f"plain autodiff of the same formulas materialises dozens of intermediates ({plain / grad:.1f}x "
        "slower in this run).",
        "",
        "Where we are behind: "
        + (
            "the forward targets were missed in this run, with the machine shared (load average above); "
            if not (speedup >= 10 and fwd < 40)
            else ""
        )
        + f"the forward is {fwd / 15:.1f}x the ~15 ms memory-traffic bound (XLA:CPU gives a loop one "
        "output, so the mask is a second pass over the inputs, and the edge loop uses 4 vector lanes "
        "per pair). The gradient has no target in the issue; it is about "
        f"{grad / fwd:.0f}x the forward: its cotangent loop evaluates the per-axis closed form and its "
        "derivatives in 18 lanes per pair, and its five outputs (160 bytes per pair) are written by "
        "five further loops.",
        "",
        "Precision: the float32 error against a float64 evaluation of the same pairs is a few ulp of "
        "the edge's offset from the principal point (|u - cx| reaches ~1000 px here, where one float32 "
        "ulp is 6e-5 px). The camera-frame formulation avoids the cancellation of the matrix form, "
        "where C* = P Q* P^T is assembled from world-frame terms of order |t|^2 f^2 and the "
        "discriminant C13^2 - C11 C33 is a difference of large, nearly equal numbers; that is the "
        'numpy column\'s larger error and most of the "difference to numpy".',
        "",
    ]
    study = r.get("study", {})
    find = lambda prefix: next((v for k, v in study.items() if k.startswith(prefix)), None)
    ref, pinned, legacy, soa = find("reference"), find("pinned"), find("XLA:CPU legacy"), find("inputs stored")
    f = lambda res: res["jax_project_bbox_ms_per_million"]
    g = lambda res: res["grad_all_inputs_ms_per_million"]
    if ref and pinned:
        lines += [
            "Threads: XLA:CPU splits large loop fusions over its intra-op thread pool (one thread per "
            f"core). Pinned to one core: forward {f(pinned):.1f} ms, gradient {g(pinned):.0f} ms; on both "
            f"cores: {f(ref):.1f} ms and {g(ref):.0f} ms ({f(pinned) / f(ref):.1f}x and "
            f"{g(pinned) / g(ref):.1f}x). The second core is shared with other jobs, so this ratio "
            "moves from run to run.",
            "",
        ]
    if ref and legacy:
        lines += [
            "XLA flags: with the legacy loop emitter (`XLA_FLAGS=--xla_cpu_use_fusion_emitters=false`) the "
            f"forward took {f(legacy):.1f} ms and the gradient {g(legacy):.0f} ms (default emitter "
            f"{f(ref):.1f} / {g(ref):.0f} ms). Flags are process-wide and must be set before JAX "
            "starts, so the library sets none; the benchmark reports the default.",
            "",
        ]
    if ref and soa:
        lines += [
            "Input layout: the library takes batch-leading arrays, so its loops read each component "
            "with a stride of 9 or 16 floats. Stored component-major instead (batch axis last, moved "
            "to the front inside `jit`, which XLA folds into the loops' reads rather than copying): "
            f"forward {f(soa):.1f} ms, gradient {g(soa):.0f} ms (batch-leading {f(ref):.1f} / "
            f"{g(ref):.0f} ms).",
            "",
        ]
    return lines


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--study", action="store_true", help="also measure threads / XLA emitter / layout")
    parser.add_argument("--layout", default="batch-leading", choices=["batch-leading", "component-major"])
    parser.add_argument("--measure-only", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--md-from-json", action="store_true", help="only rebuild the markdown from the JSON")
    args = parser.parse_args()
    if args.md_from_json:
        print(write_md(json.loads((RESULTS / "geometry.json").read_text())))
        return
    if args.measure_only:
        out = measure(args.pairs, args.repeats, with_numpy=False, layout=args.layout)
        pathlib.Path(args.measure_only).write_text(json.dumps(out))
        return

    load_before = os.getloadavg()[0]
    rows = measure(args.pairs, args.repeats)
    load_after = os.getloadavg()[0]
    rows.update(
        {
            "devices": str(jax.devices()),
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()}-core CPU (shared, noisy)",
            "load_average_1min_before_after": [load_before, load_after],
            "jax_version": jax.__version__,
            "date": time.strftime("%Y-%m-%d", time.gmtime()),
        }
    )
    if args.study:
        rows["study"] = {label: res for label, res in study(args.pairs, args.repeats)}
    cmd = f"python benchmarks/geometry.py --pairs {args.pairs} --repeats {args.repeats}" + (
        " --study" if args.study else ""
    )
    rows["command"] = cmd
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "geometry.json").write_text(json.dumps(rows, indent=2))
    print(write_md(rows))


def write_md(r):
    """benchmarks/results/geometry.md from the JSON rows (``--md-from-json`` rebuilds it alone)."""
    table = [
        "| quantity | value |",
        "|---|---|",
        f"| jaxsem `project_bbox`, jitted float32 | {r['jax_project_bbox_ms_per_million']:.1f} ms per million |",
        f"| numpy matrix formulation (peer) | {r['numpy_matrix_formulation_ms_per_million']:.0f} ms per million |",
        f"| speed-up vs numpy (same run) | {r['speedup_vs_numpy']:.1f}x |",
        f"| gradient of a box loss w.r.t. R, c, r, K, pose | {r['grad_all_inputs_ms_per_million']:.1f} ms per million |",
        f"| same gradient by plain autodiff of the same forward (no custom JVP) | {r['grad_plain_autodiff_ms_per_million']:.1f} ms per million |",
        f"| compile: forward / gradient | {r['compile_forward_s']:.2f} s / {r['compile_grad_s']:.2f} s |",
        f"| max difference to numpy (valid pairs) | {r['max_abs_diff_px_vs_numpy']:.2e} px |",
        f"| max error vs float64, jaxsem float32 / numpy float32 | {r['max_abs_err_px_jax_float32_vs_float64']:.2e} px / {r['max_abs_err_px_numpy_float32_vs_float64']:.2e} px |",
        f"| valid pairs | {100 * r['valid_fraction']:.1f} % |",
    ]
    load_before, load_after = r["load_average_1min_before_after"]
    md = [
        "## Geometry core: `project_bbox` throughput (issue 2)",
        "",
        f"Command: `{r['command']}`; {r['date']}; {r['machine']}, 1-minute load average "
        f"{load_before:.1f} before / {load_after:.1f} after (other jobs share the cores); jax "
        f"{r['jax_version']}; medians after warm-up, `block_until_ready`, measurements interleaved "
        "round-robin so that load changes hit all of them alike.",
        "",
        *table,
        "",
    ]
    if r.get("study"):
        md += (
            [
                "| setting (separate processes, after the main table) | forward | gradient | compile fwd / grad |",
                "|---|---|---|---|",
            ]
            + [
                f"| {label} | {res['jax_project_bbox_ms_per_million']:.1f} ms | {res['grad_all_inputs_ms_per_million']:.1f} ms"
                f" | {res['compile_forward_s']:.2f} s / {res['compile_grad_s']:.2f} s |"
                for label, res in r["study"].items()
            ]
            + [""]
        )
    md += notes(r)
    text = "\n".join(md)
    (RESULTS / "geometry.md").write_text(text)
    return text


if __name__ == "__main__":
    main()
