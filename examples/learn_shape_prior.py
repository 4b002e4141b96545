"""Learn a class shape-prior mean by differentiating solved maps through the batch solver.

Simulated few-view Forward maps of cars are solved with ROSHAN (``jaxsem.slam.solve_batch``,
``method="optimistix"``: the Schur Levenberg-Marquardt on the tangent delta); the loss is the mean squared error of the solved radii against
the truth, and its gradient w.r.t. the ``car`` prior mean flows through the solution by the
implicit function theorem (optimistix's implicit adjoint). optax Adam updates the mean, which
starts from a deliberately wrong value.

Run: ``python examples/learn_shape_prior.py --steps 30 --maps 8 --out /tmp/prior``
"""

from __future__ import annotations

import argparse
import pathlib
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

from jaxsem import factors as F, slam  # noqa: E402


def make_maps(num_maps, seed, num_frames, num_objects):
    maps = [
        slam.toy_map(
            seed + k,
            num_objects=num_objects,
            num_frames=num_frames,
            path="forward",
            size_noise=0.05,
            capacity=(num_frames, num_frames * num_objects, num_objects),
        )
        for k in range(num_maps)
    ]
    problems = slam.stack_problems([m[0] for m in maps])
    truths = slam.stack_problems([m[1] for m in maps])
    return problems, truths


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--maps", type=int, default=8)
    ap.add_argument("--frames", type=int, default=4, help="frames per map (few views: the prior matters)")
    ap.add_argument("--objects", type=int, default=2)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--init-scale", type=float, default=0.7, help="initial mean = scale * table mean")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("learn_shape_prior_out"))
    args = ap.parse_args(argv)

    problems, truths = make_maps(args.maps, args.seed, args.frames, args.objects)
    mean0, sigma = F.shape_prior_table()
    car = F.class_index("car")
    true_mean = mean0[car]

    def loss_fn(log_mean):
        mean = mean0.at[car].set(jnp.exp(log_mean))
        cfg = slam.SolverConfig(shape_prior_mean=mean, shape_prior_sigma=sigma, max_steps=40)

        def one(p, t):
            est, _ = slam.solve_batch(p, slam.initialize(p, cfg), cfg, method="optimistix")
            err = jnp.sum(jnp.square(est.radii - t.radii), -1)
            return jnp.sum(jnp.where(p.object_mask, err, 0.0)) / jnp.maximum(jnp.sum(p.object_mask), 1)

        return jnp.mean(jax.vmap(one)(problems, truths))

    step_fn = jax.jit(jax.value_and_grad(loss_fn))
    opt = optax.adam(args.lr)
    param = jnp.log(args.init_scale * true_mean)
    state = opt.init(param)
    history = []
    t0 = time.time()
    for step in range(args.steps):
        loss, grad = step_fn(param)
        updates, state = opt.update(grad, state, param)
        param = optax.apply_updates(param, updates)
        history.append((float(loss), np.exp(np.asarray(param))))
        print(
            f"step {step:3d}  loss {float(loss):.4f}  car mean radii {np.round(np.exp(np.asarray(param)), 3)}"
            f"  ({time.time() - t0:.0f} s)",
            flush=True,
        )
    print(f"table mean {np.asarray(true_mean)}  learned {np.exp(np.asarray(param))}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args.out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    ax[0].plot([h[0] for h in history])
    ax[0].set_xlabel("Adam step")
    ax[0].set_ylabel("mean squared radii error (m^2)")
    means = np.array([h[1] for h in history])
    for i, name in enumerate(["length", "width", "height"]):
        ax[1].plot(means[:, i], label=f"{name} radius")
        ax[1].axhline(float(true_mean[i]), ls="--", c=f"C{i}")
    ax[1].set_xlabel("Adam step")
    ax[1].set_ylabel("car prior mean (m)")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(args.out / "learn_shape_prior.png", dpi=100)
    print(f"figure: {args.out / 'learn_shape_prior.png'}")


if __name__ == "__main__":
    main()
