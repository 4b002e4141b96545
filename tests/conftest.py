"""Test environment: float64 on (precision checks), headless MuJoCo, small thread pools.

Tests that check float32 behaviour pass float32 arrays explicitly.

Strict settings for the whole suite (issue 23 item 6), optimistix-style:

- dtype promotion is "strict" in every test, the slow ones included: no silent float32 ->
  float64, int -> float or int32 <-> int64 mixing, so a float32 input that comes back float64
  (or an index array of another integer width under x64) fails the test that feeds it.
  Weak-typed Python scalars still promote. Library code casts explicitly (``astype``,
  ``jnp.asarray(x, dtype)``); a test whose own code runs optax asks for ``optax_promotion``.
- warnings are errors (pyproject's ``filterwarnings``).
- rank promotion stays allowed (``jax_numpy_rank_promotion`` "allow"), kept with the measured
  reason: with "raise", 55 of 278 tests in 12 representative modules (core geometry, factors,
  Schur LM, metrics, sim, planning, VoluMon and LSD models) failed, every one inside the
  library, at 18 places that use numpy broadcasting as written idiom: ``(N, 2) - (2,)``
  offsets, ``R * radii[..., None, :]``, one-hot ``x[..., None] == arange(n)``, a (3, 3) ``K``
  applied to (N, 3) points (the documented leading-batch-axes API itself). "warn" is the same
  as "raise" here (warnings are errors). Spelling out every such axis would make the code
  harder to read without catching a bug; the dtype rule above is the one that does.
"""

import atexit
import gc
import os
import pathlib
import shutil
import sys
import tempfile

os.environ.setdefault("MUJOCO_GL", "egl")
# Under pytest-xdist (the README's command runs two worker processes) each worker gets folders of
# its own below: the workers inherit the controlling process's environment, and two workers
# writing one run folder or one compilation cache would step on each other.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _name in ("JAXSEM_RUNS_DIR", "JAXSEM_CACHE_DIR"):
        os.environ.pop(_name, None)
    # On a GPU machine, two workers that each take 75 % of the device's memory at start-up would
    # leave the second one nothing: allocate as needed.
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
# Commands run by the tests write their run directories (config.json, summary.json) here, not in
# the checkout's runs/.
_made_here = []  # the temporary folders this process made, removed when it exits


def _temporary(name: str, prefix: str) -> None:
    if name not in os.environ:
        os.environ[name] = tempfile.mkdtemp(prefix=prefix)
        _made_here.append(os.environ[name])


atexit.register(lambda: [shutil.rmtree(d, ignore_errors=True) for d in _made_here])
_temporary("JAXSEM_RUNS_DIR", "jaxsem_test_runs_")
# LLVM's optimisation level 0 for the compiled CPU code, and XLA's older elemental emitters in
# place of its fusion emitters: the suite is compile-bound (most of a test's time is XLA's backend
# compiling small programs), and at level 0 the older emitters compile such programs about twice
# as fast. Together they make the fast suite about two fifths quicker, and the slow suite's
# heavy modules compile in half the time. They change how the machine code is generated, not the
# programs XLA builds, and the suite passes under the defaults too; XLA_FLAGS set outside the
# suite win. Two programs that should agree (a network grown by a branch that starts at zero, a
# batch solved by ``lax.map`` against each map solved alone) are compared to rounding, not bit
# for bit: XLA compiles them apart, and under either emitter their rounding may differ. Child
# processes that shard programs over four host devices keep XLA's own emitters
# (``four_cpu_child``).
_OWN_FLAGS = "XLA_FLAGS" not in os.environ
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=true --xla_backend_optimization_level=0")
_FAST_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
if _OWN_FLAGS:
    os.environ["XLA_FLAGS"] += " " + _FAST_EMITTERS


# Commands run in-process turn JAX's persistent compilation cache on: give the session its own
# folder (never the user's ~/.cache/jaxsem, which other processes may be writing), and
# _restore_compilation_cache below turns it off again after each test.
_temporary("JAXSEM_CACHE_DIR", "jaxsem_test_cache_")
# ... and commands run by the tests (in-process or as subprocesses) leave it off unless a test asks
# for it (tests/integration/test_run_dir.py deletes this variable to test the default).
os.environ["JAXSEM_NO_COMPILATION_CACHE"] = "1"

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_compilation_cache_dir", None)
jax.config.update("jax_numpy_dtype_promotion", "strict")


import pytest  # noqa: E402


@pytest.fixture(autouse=True)
def _restore_compilation_cache():
    """A test that runs a command in-process (which enables JAX's persistent compilation cache
    for the rest of the process) leaves the cache setting as it found it: later tests compile
    in memory only, as they would run alone."""
    yield
    if jax.config.jax_compilation_cache_dir is not None:  # pyright: ignore[reportAttributeAccessIssue]
        jax.config.update("jax_compilation_cache_dir", None)
    # JAX opens the cache folder once per process and keeps writing to it even after the setting
    # is unset (a test's own fixture may already have unset it): forget it.
    from jax._src import compilation_cache

    if getattr(compilation_cache, "_cache", None) is not None:
        compilation_cache.reset_cache()


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """After each test module, JAX's compiled programs are dropped. Every compiled CPU program
    keeps its own memory mappings, and a full run in one process compiles thousands of them:
    without this, XLA aborted inside a later compile (twice in CI and once here, in
    test_volumon_device.py, at 7 GB resident), most likely at the kernel's limit on mappings
    per process (vm.max_map_count, 65530); with it the count stays in the low thousands."""
    yield
    jax.clear_caches()
    gc.collect()


def pytest_collection_modifyitems(config, items):
    """Test ids must not contain the word "error" in lower case: the CI's report of this project
    twice listed every such test as one it could not collect (while they collect and pass with
    pytest here), so names say "refused", "metric", "failure" ... instead."""
    bad = [item.nodeid for item in items if "error" in item.nodeid]
    if bad:
        raise pytest.UsageError("test ids containing 'error' (rename them): " + ", ".join(bad[:10]))


class _Compiles:
    """Counts XLA compilations (JAX's backend-compile event) inside a ``with`` block."""

    def __enter__(self):
        self.count = 0
        jax.monitoring.register_event_duration_secs_listener(self._listen)
        return self

    def _listen(self, event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            self.count += 1

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self._listen)


@pytest.fixture
def optax_promotion():
    """Standard dtype promotion for a test whose own code runs an optax optimiser (an opt-out of
    the suite's strict rule, for a third-party reason): optax 0.2.8's adam computes its bias
    correction as ``decay ** count``, a Python float and the int32 step count, which strict
    promotion refuses. The library's training steps wrap only optax's update the same way."""
    with jax.numpy_dtype_promotion("standard"):
        yield


@pytest.fixture
def compiles():
    """``with compiles() as c: ...``; then ``c.count`` is the number of XLA compilations inside
    the block (no-recompile tests: a second call with new values of the same shapes)."""
    return _Compiles


@pytest.fixture
def run_cli(capsys):
    """``run_cli(argv)``: ``jaxsem *argv`` in-process, as a shell would see it: (exit status,
    stdout, stderr)."""
    from jaxsem import cli

    def run(argv):
        try:
            status = cli.main(argv)
        except SystemExit as exc:
            if isinstance(exc.code, str):  # a message about the input: exit status 2 (run_main's rule)
                print(exc.code, file=sys.stderr)
                status = 2
            else:
                status = exc.code or 0
        out, err = capsys.readouterr()
        return status, out, err

    return run


@pytest.fixture
def axes_titles(monkeypatch):
    """The titles set on matplotlib axes during the test, in order (``Agg`` backend); the titles
    are still set."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.axes

    titles = []
    original = matplotlib.axes.Axes.set_title

    def record(self, label, *args, **kwargs):
        titles.append(label)
        return original(self, label, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "set_title", record)
    return titles


@pytest.fixture
def script():
    """``script("benchmarks/lsd/lsd_real.py")``: a repository script imported as a module (named by
    its stem), for tests of a benchmark's or a command's own functions."""
    import importlib.util

    root = pathlib.Path(__file__).resolve().parents[1]

    def load(relpath: str):
        path = root / relpath
        spec = importlib.util.spec_from_file_location(path.stem, path)
        assert spec is not None and spec.loader is not None, relpath
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod

    return load


@pytest.fixture(scope="session")
def four_cpu_child():
    """``four_cpu_child(code, *args)``: runs ``python -c code *args`` in a subprocess with four host
    CPU devices (``--xla_force_host_platform_device_count=4``) and returns the JSON of its last
    ``RESULT {...}`` line (the test fails with the child's stderr if it has none or exits non-zero)."""
    import json
    import subprocess

    def run(code: str, *args: str) -> dict:
        env = dict(os.environ)
        # The child compiles with XLA's own emitters: under the elemental ones the sharded programs
        # stray from the one-device program beyond these tests' tolerances (1.6 against 1e-8).
        flags = env.get("XLA_FLAGS", "").replace(_FAST_EMITTERS, "")
        env["XLA_FLAGS"] = " ".join(flags.split() + ["--xla_force_host_platform_device_count=4"])
        env.setdefault("JAX_PLATFORMS", "cpu")
        proc = subprocess.run(
            [sys.executable, "-c", code, *args], check=False, env=env, capture_output=True, text=True, timeout=900
        )
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        assert proc.returncode == 0 and lines, proc.stderr[-4000:]
        return json.loads(lines[-1][len("RESULT ") :])

    return run
