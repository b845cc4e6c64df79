"""train.portable (sweep/portable.py): the setting reaches torch (MKL, ATen), XLA, numba and NumPy before they
compute, in a fresh process as `python -m sweep` starts one; the command line decides it; a config asking for the
other mode is one error line; numba's cache never hands a host-tuned build to a portable run; runs carry the CPU
and the mode as tags; Adam's step does not depend on MKL's code path. Whether the numbers themselves are equal on
two CPU models is not tested here (README, Determinism); tests/test_reference_history.py compares them bitwise on
the CPU that wrote its file (and on any other with REFERENCE_BITWISE=1)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from conftest import new_store
from sweep import portable

ROOT = Path(__file__).resolve().parents[1]

# What each library computes with, read after `import sweep` and a first computation of each (printed as JSON).
PROBE = r"""
import sys
import sweep  # first, as `python -m sweep` does
import ctypes, json, os
import numpy as np, torch, numba, jax, jax.numpy as jnp
from numpy._core._multiarray_umath import __cpu_features__
import sweep.agents.jax_ppo  # noqa: F401  (adds the learner's own XLA flags)
torch.matmul(torch.ones(2, 2), torch.ones(2, 2))
float(jax.jit(jnp.sum)(np.ones(3, np.float32)))
lib = ctypes.CDLL(os.path.join(os.path.dirname(torch.__file__), "lib", "libtorch_cpu.so"))
print(json.dumps({"active": sweep.portable.active(), "aten": torch.backends.cpu.get_cpu_capability(),
                  "mkl_branch": lib.mkl_serv_cbwr_get(ctypes.c_int(1)), "numba_cpu": numba.core.config.CPU_NAME,
                  "numba_features": numba.core.config.CPU_FEATURES, "xla_flags": os.environ.get("XLA_FLAGS", ""),
                  "numpy_v4": bool(__cpu_features__.get("X86_V4"))}))
"""
MKL_CBWR_BRANCH_OFF, MKL_CBWR_COMPATIBLE = 1, 3


def clean_env() -> dict[str, str]:
    """This environment without any float-mode setting (the switch, the settings, XLA_FLAGS)."""
    return {k: v for k, v in os.environ.items() if k not in (portable.SWITCH, *portable.SETTINGS, "XLA_FLAGS")}


def probe(*args: str, **env: str) -> dict:
    clean = clean_env()
    proc = subprocess.run([sys.executable, "-c", PROBE, *args], env={**clean, **env}, capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_portable_mode_reaches_every_library_before_it_computes():
    got = probe()  # the default: conf/config.yaml's train.portable
    assert got["active"] is True
    assert got["aten"] == "AVX2" and got["mkl_branch"] == MKL_CBWR_COMPATIBLE
    assert got["numba_cpu"] == portable.LEVEL and got["numba_features"] == portable.NUMBA_FEATURES
    flags = got["xla_flags"].split()
    assert "--xla_cpu_max_isa=AVX2" in flags and "--xla_cpu_multi_thread_eigen=false" in flags  # both kept
    assert got["numpy_v4"] is False


def test_native_mode_from_the_command_line_leaves_every_library_to_the_host():
    flags = set(next(line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags")).split())
    avx512 = {"avx512f", "avx512cd", "avx512vl", "avx512bw", "avx512dq"} <= flags  # x86-64-v4
    for got in (probe("train.portable=false"), probe(SWEEP_PORTABLE="0")):
        assert got["active"] is False and got["mkl_branch"] == MKL_CBWR_BRANCH_OFF and got["numba_cpu"] is None
        assert "--xla_cpu_max_isa=AVX2" not in got["xla_flags"].split()
        assert "--xla_cpu_multi_thread_eigen=false" in got["xla_flags"].split()
        if avx512:  # the host's own vector width, not the portable cap
            assert got["aten"].startswith("AVX512") and got["numpy_v4"] is True


def test_the_mode_comes_from_the_command_line_then_the_switch_then_the_config(monkeypatch):
    monkeypatch.delenv(portable.SWITCH, raising=False)
    assert portable.requested(["agent=ppo", "train.portable=false", "-m"]) is False
    assert portable.requested(["train.portable=true"]) is True
    assert portable.requested(["train.portable=true,false"]) is True  # a sweep over both: left to check()
    assert portable.requested([]) is True  # conf/config.yaml
    monkeypatch.setenv(portable.SWITCH, "0")  # what a parent process decided (a joblib worker's only clue)
    assert portable.requested([]) is False
    assert portable.requested(["train.portable=true"]) is True  # the command line wins


def test_a_native_child_of_a_portable_parent_drops_the_settings():
    """A process started from a portable one (this test process, a notebook) with train.portable=false on its
    command line computes natively: the settings it inherited are removed before any library starts."""
    parent = portable.environment(True, clean_env())
    proc = subprocess.run([sys.executable, "-c", PROBE, "train.portable=false"], env=parent, capture_output=True,
                          text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got["active"] is False and got["mkl_branch"] == MKL_CBWR_BRANCH_OFF and got["numba_cpu"] is None
    assert "--xla_cpu_max_isa=AVX2" not in got["xla_flags"].split()


def test_numpy_imported_before_sweep_is_not_portable():
    """NumPy reads its dispatch setting at import: a script that imports it before sweep is not in portable mode
    on an AVX-512 CPU, and run() says why."""
    code = ("import numpy, sweep, sweep.portable as p; print(p.active(), p.numpy_uncapped()); "
            "p.check(True)")
    proc = subprocess.run([sys.executable, "-c", code], env=clean_env(), capture_output=True, text=True,
                          timeout=300)  # nothing set at start: NumPy starts native, then sweep activates
    if "avx512f" not in Path("/proc/cpuinfo").read_text():
        pytest.skip("no AVX-512 on this CPU: NumPy's dispatch is x86-64-v3 at most anyway")
    assert proc.stdout.split()[:2] == ["False", "True"]
    assert proc.returncode == 1 and "NumPy was imported before sweep: import sweep first" in proc.stderr


def test_a_config_asking_for_the_other_mode_is_one_error_line_before_training(tmp_path):
    env = clean_env()
    uri = new_store(tmp_path / "mlflow.db")
    # a parent decided native (SWEEP_PORTABLE=0), the config (conf/config.yaml) asks for portable
    proc = subprocess.run([sys.executable, "-m", "sweep", "train.total_timesteps=512", f"hydra.run.dir={tmp_path / 'out'}"],
                          env={**env, portable.SWITCH: "0", "MLFLOW_TRACKING_URI": uri}, cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and lines[-1].startswith("sweep: invalid config: train.portable=true, but this "
                                                         "process computes in native mode"), proc.stderr[-2000:]
    client = MlflowClient(uri)  # no run was started
    assert not client.search_runs([e.experiment_id for e in client.search_experiments()])


CACHED = '''
import numba, numpy as np
@numba.njit(cache=True, fastmath=True)
def dot(a, b):
    s = np.float32(0)
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s
'''
CALL = ("import sys; sys.path.insert(0, sys.argv[1]); import sweep, numpy as np, cached; "
        "cached.dot(np.ones(8, np.float32), np.ones(8, np.float32)); "
        "print(len(cached.dot.stats.cache_hits), len(cached.dot.stats.cache_misses))")


def test_numba_never_loads_a_host_tuned_build_into_a_portable_run(tmp_path):
    """A function cached by a native run is compiled anew (a cache miss) by the first portable run, which caches
    its own build: the second portable run loads that one."""
    (tmp_path / "cached.py").write_text(CACHED)
    env = {**clean_env(), "NUMBA_CACHE_DIR": str(tmp_path / "cache")}

    def call(mode: str) -> tuple[int, int]:
        proc = subprocess.run([sys.executable, "-c", CALL, str(tmp_path)], env={**env, portable.SWITCH: mode},
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        hits, misses = proc.stdout.split()
        return int(hits), int(misses)

    assert call("0") == (0, 1)  # native: compiled and cached
    assert call("0") == (1, 0)  # native again: loaded
    assert call("1") == (0, 1)  # portable: not the native build
    assert call("1") == (1, 0)  # portable again: its own build


# 50 Adam steps on fixed gradients, in a portable process whose MKL branch is then set by MKL_CBWR (MKL reads it at
# its first call): the md5 of the parameters, with the project's Adam (networks.adam_kwargs) and with torch's default.
ADAM_STEPS = r"""
import sys, os, hashlib
import sweep
os.environ["MKL_CBWR"] = sys.argv[1]
import numpy as np, torch
from sweep.agents.networks import adam_kwargs
torch.set_num_threads(1)
out = []
for kwargs in (adam_kwargs(1e-5), {"eps": 1e-5}):
    rng = np.random.default_rng(0)
    p = torch.nn.Parameter(torch.from_numpy(rng.standard_normal(4096).astype(np.float32)))
    opt = torch.optim.Adam([p], lr=3e-4, **kwargs)
    for _ in range(50):
        p.grad = torch.from_numpy(rng.standard_normal(4096).astype(np.float32) * np.float32(10.0 ** rng.integers(-6, 2)))
        opt.step()
    out.append(hashlib.md5(p.detach().numpy().tobytes()).hexdigest())
print(*out)
"""


def test_adam_steps_the_same_whatever_mkl_branch_computes_it():
    """The project's Adam (fused: the CPU's exactly rounded square root) does not go through MKL: its steps are
    equal under MKL's portable branch and its AVX2, SSE4.2 and host (AUTO) ones. torch's default Adam takes the
    square root from MKL's vector math, which moves with the branch (and, in the portable branch, parted an AMD
    EPYC and an Intel Xeon after one update; README, Determinism), so the comparison can fail."""
    def steps(branch: str) -> list[str]:
        proc = subprocess.run([sys.executable, "-c", ADAM_STEPS, branch], env=clean_env(), capture_output=True,
                              text=True, timeout=300, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc.stdout.split()

    (fused, loop), *others = [steps(b) for b in ("COMPATIBLE", "AVX2", "SSE4_2", "AUTO")]
    assert all(f == fused for f, _ in others)
    if all(lp == loop for _, lp in others):   # the AMD EPYC (12-06): MKL's branches give the default Adam one result
        pytest.skip("on this CPU MKL's branches do not change torch's default Adam: the comparison cannot fail here")
    # on the Intel Xeon MKL's branch changes torch's default Adam (AVX2, AUTO), so the comparison can fail there


def test_a_run_records_the_cpu_and_the_mode_as_tags(tmp_path, monkeypatch):
    import sweep.run
    from conftest import TINY, compose_cfg

    assert portable.active(), "conftest.py imports sweep first: the test process computes in portable mode"
    uri = new_store(tmp_path / "mlflow.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("SWEEP_CHECKPOINT_DIR", str(tmp_path / "ckpt"))
    run_id = sweep.run.run(compose_cfg(TINY + ["env.backend=fast"]), tmp_path / "out")
    tags = MlflowClient(uri).get_run(run_id).data.tags
    assert tags["portable"] == "true" and tags["cpu_model"] == portable.cpu_model() and tags["cpu_model"]
    assert len(tags["cpu_flags"]) == 8
