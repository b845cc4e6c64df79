"""Portable floats (``train.portable``): every library's float code pinned to what any x86-64-v3 CPU runs alike.

The float results of torch (MKL, ATen's vector kernels, oneDNN), XLA, numba and NumPy can depend on the CPU
they run on: the instruction set each picks for the host changes the rounding and the order of reductions.
Measured on this machine kind (README, "Determinism"): the component that makes a run part between two AMD EPYC
models is MKL. SB3's initial weights (``torch.nn.init.orthogonal_``, used by both learners) come from a QR
decomposition in MKL, whose code path on this CPU moves them by an ulp; the run's very first rollout then differs,
and the runs never meet again. Capping XLA at AVX2 or compiling numba for x86-64-v3 instead of the host's AVX-512
gave the same numbers over 51k steps of the study's command, so those caps are precautions for CPUs that differ
more (no AVX-512, other vendors), at no measured cost.

Portable mode pins every one of them to code that any x86-64 CPU with AVX2 and FMA (x86-64-v3) runs alike:

* torch: ``MKL_CBWR=COMPATIBLE`` (MKL's conditional numerical reproducibility; on AMD CPUs MKL ignores the
  AVX2/AVX-512 branches and falls back to AUTO, which depends on the CPU: COMPATIBLE is the branch that holds on
  Intel and AMD alike), ``ATEN_CPU_CAPABILITY=avx2``;
* oneDNN, in torch and in XLA (XLA's dots run in oneDNN, which picks its kernel at run time whatever XLA's own
  ISA cap): ``ONEDNN_MAX_CPU_ISA=AVX2``;
* XLA's own code (the JAX learner): ``--xla_cpu_max_isa=AVX2`` in ``XLA_FLAGS``;
* numba: ``NUMBA_CPU_NAME=x86-64-v3`` with that level's features (``NUMBA_CPU_FEATURES``); numba's on-disk cache
  keys a compiled function by CPU name and features, so a host-tuned build is never loaded into a portable run;
* NumPy: ``NPY_DISABLE_CPU_FEATURES`` drops its AVX-512 dispatch targets (the diagnostics' reductions).

Each library reads its variable once, when it first initialises (numba and NumPy at import, MKL and ATen at
their first call, XLA when its backend starts). So the mode is fixed per process, when ``sweep`` is first
imported (``sweep/__init__.py`` calls ``activate``; import it before NumPy): from a ``train.portable=``
override on the command line, else from ``SWEEP_PORTABLE=0|1``, else from conf/config.yaml. The decision goes
into ``SWEEP_PORTABLE``, so the joblib workers a sweep starts (whose command line is not the sweep's) inherit it.
``run()`` checks that the config asks for the mode the process has (``check``). OpenBLAS (NumPy's linear algebra, diagnostics only) is left as the
machine sets it (``OPENBLAS_CORETYPE``).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

LEVEL = "x86-64-v3"
NUMBA_FEATURES = "+avx,+avx2,+bmi,+bmi2,+cx16,+f16c,+fma,+lzcnt,+movbe,+popcnt,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave"
SETTINGS = {
    "MKL_CBWR": "COMPATIBLE",
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "NUMBA_CPU_NAME": LEVEL,
    "NUMBA_CPU_FEATURES": NUMBA_FEATURES,
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
}
XLA_FLAGS = ("--xla_cpu_max_isa=AVX2",)
SWITCH = "SWEEP_PORTABLE"
CONFIG = Path(__file__).resolve().parents[2] / "conf" / "config.yaml"


def requested(argv: list[str] | None = None) -> bool:
    """The mode this process is to run in: a ``train.portable=`` override in ``argv`` (one value; a sweep over
    both is left to ``check``), else ``SWEEP_PORTABLE`` (what a parent process decided), else conf/config.yaml."""
    for arg in sys.argv[1:] if argv is None else argv:
        key, _, value = arg.lstrip("+").partition("=")
        if key == "train.portable" and value.lower() in ("true", "false"):
            return value.lower() == "true"
    switch = os.environ.get(SWITCH)
    if switch is not None:
        return switch.strip().lower() not in ("0", "false", "no", "")
    from omegaconf import OmegaConf

    return bool(OmegaConf.load(CONFIG).train.portable)


def activate(portable: bool) -> None:
    """Put the mode into this process's environment before torch, XLA, numba and NumPy initialise (a native
    process drops the settings a portable parent passed down; numba's config is re-read if numba was imported)."""
    env = environment(portable)
    for key in set(os.environ) - set(env):
        del os.environ[key]
    os.environ.update(env)
    if "numba" in sys.modules:
        from numba.core import config

        config.reload_config()


def environment(portable: bool, base=None) -> dict[str, str]:
    """The environment of a new process in the given mode: ``base`` (default: this process's) with the switch set
    and the settings added (portable) or the ones this module added removed (native)."""
    env = dict(os.environ if base is None else base)
    env[SWITCH] = "1" if portable else "0"
    flags = [f for f in env.get("XLA_FLAGS", "").split() if f not in XLA_FLAGS]
    for key, value in SETTINGS.items():
        if env.get(key) == value:
            del env[key]
    if portable:
        env.update(SETTINGS)
        flags += XLA_FLAGS
    env["XLA_FLAGS"] = " ".join(flags)
    return env


def numpy_uncapped() -> bool:
    """NumPy was imported before the settings and dispatches AVX-512 code (``import sweep`` came too late)."""
    if "numpy" not in sys.modules:
        return False
    from numpy._core._multiarray_umath import __cpu_features__

    return bool(__cpu_features__.get("X86_V4")) and "X86_V4" in os.environ.get("NPY_DISABLE_CPU_FEATURES", "")


def active() -> bool:
    """Whether this process computes in portable mode: its environment holds every setting, and NumPy (the one
    library read at import that cannot be re-read) started under them."""
    flags = os.environ.get("XLA_FLAGS", "").split()
    return (os.environ.get(SWITCH) == "1" and all(os.environ.get(k) == v for k, v in SETTINGS.items())
            and all(f in flags for f in XLA_FLAGS) and not numpy_uncapped())


def check(portable: bool) -> None:
    """ValueError (one line) if the config asks for another mode than the process has."""
    if bool(portable) != active():
        have = "portable" if active() else "native"
        late = " (NumPy was imported before sweep: import sweep first)" if numpy_uncapped() else ""
        raise ValueError(f"train.portable={str(bool(portable)).lower()}, but this process computes in {have} mode"
                         f"{late}, fixed when it started: set train.portable on the command line (not in a preset) "
                         "or SWEEP_PORTABLE=0|1, and use one value for every job of a sweep")


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), for the run's tags."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine()


def cpu_flags_hash() -> str:
    """A short hash of the CPU's feature flags: two machines with the same model name can differ in them."""
    import hashlib

    try:
        flags = next(line for line in Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("flags"))
    except (OSError, StopIteration):
        return "?"
    return hashlib.sha256(" ".join(sorted(flags.split(":", 1)[1].split())).encode()).hexdigest()[:8]
