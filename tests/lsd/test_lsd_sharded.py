"""jaxsem.lsd.run_trials over a device mesh: 4 forced CPU devices give the records of one device.

The check runs in a subprocess started with ``XLA_FLAGS=--xla_force_host_platform_device_count=4``
(the flag must be set before JAX starts), as in ``tests/slam/test_parallel.py``: a tiny Table 3.1
setting (one building, five tasks, the LSD planner with a small random network) runs without a mesh, on a 4-device
mesh and on a 1-device mesh, and the child reports the records (timings dropped) as JSON.
"""

import json
import os
import subprocess
import sys
import textwrap

import pytest

CHILD = textwrap.dedent(
    r"""
    import json
    import jax
    import jax.numpy as jnp
    from jaxsem import parallel
    from jaxsem.lsd import LSDSampler, run_trials
    from jaxsem.models import LSDConfig, init_lsd
    from jaxsem.planning import generate_building

    model, params = init_lsd(jax.random.PRNGKey(3), LSDConfig(map_size=160, features=(4, 8), context_features=4))
    seen = {"inputs": [], "params": []}

    class Probe:
        # The LSD sampler, recording where the loop's arrays and its parameters live.

        def __init__(self, inner):
            self.inner = inner

        def on_device(self, device):
            return Probe(self.inner.on_device(device))

        def __call__(self, inputs):
            seen["inputs"] += [str(d) for d in inputs.occupancy.devices()]
            seen["params"] += [str(d) for d in jax.tree_util.tree_leaves(self.inner.params)[0].devices()]
            return self.inner(inputs)

    lsd = Probe(LSDSampler(model, params))
    buildings = [generate_building(0, "test")]
    # One planner and a few steps: every device compiles the loop's jitted pieces for itself,
    # which is most of the time.
    kw = dict(sets=("II",), ns=(40,), trials=5, seed=2, max_steps=4, progress=False,
              variants={"lsd": (lsd, {})}, base=False)

    def strip(recs):
        for r in recs:
            for v in r.values():
                if isinstance(v, dict):
                    v.pop("seconds", None)
        return recs

    out = {"devices": jax.device_count()}
    out["ref"] = strip(run_trials(buildings, None, **kw))
    seen["inputs"].clear()
    seen["params"].clear()
    out["four"] = strip(run_trials(buildings, None, mesh=parallel.devices_mesh(4), **kw))
    out["four_seen"] = {k: sorted(set(v)) for k, v in seen.items()}
    out["one"] = strip(run_trials(buildings, None, mesh=parallel.devices_mesh(1), **kw))
    try:
        run_trials(buildings, None, mesh="all", **kw)
        out["bad_mesh"] = ""
    except ValueError as exc:
        out["bad_mesh"] = str(exc)
    print("RESULT " + json.dumps(out))
    """
)


@pytest.mark.slow
def test_sharded_trials_equal_single_device_records():
    env = dict(os.environ)
    # Optimisation level 0 only makes XLA compile faster (every run of the child uses it).
    # XLA's own emitters, as in conftest's four_cpu_child: sharded programs under the elemental ones
    # stray from the one-device program.
    flags = " --xla_force_host_platform_device_count=4 --xla_backend_optimization_level=0"
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "").replace("--xla_cpu_use_fusion_emitters=false", "") + flags).strip()
    env.setdefault("JAX_PLATFORMS", "cpu")
    proc = subprocess.run(
        [sys.executable, "-c", CHILD], check=False, env=env, capture_output=True, text=True, timeout=900
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, proc.stderr[-4000:]
    out = json.loads(lines[-1][len("RESULT ") :])
    assert out["devices"] == 4
    assert len(out["ref"]) == 5
    assert out["four"] == out["ref"]
    assert out["one"] == out["ref"]
    # The five trials were dealt over all four devices, the sampler's parameters with them.
    assert len(out["four_seen"]["inputs"]) == 4
    assert out["four_seen"]["params"] == out["four_seen"]["inputs"]
    # The trials went somewhere: the robot moved in at least one of them.
    assert any(r["lsd"]["steps"] > 0 for r in out["ref"])
    assert out["bad_mesh"].startswith("mesh:")
