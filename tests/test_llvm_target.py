"""Another CPU at home: Dr.Jit's LLVM backend compiled for another CPU
(``$SPARSE_BRDF_LLVM_TARGET``), and the environment ``make test-other-cpu`` uses."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from conftest import cli_fails
from other_cpu import other_cpu, pinned_cpu
from sparse_brdf.errors import UsageError
from sparse_brdf.mitsuba_env import LLVM_TARGET_ENV, LLVM_TARGETS, set_llvm_target

pytestmark = pytest.mark.numerics

#: A child process: its LLVM target after ``set_variant``, and exp, log and sin of a ramp
#: computed by Dr.Jit.
CHILD = """
import json
import os
import drjit as dr
import numpy as np
from sparse_brdf.mitsuba_env import llvm_target, set_variant
set_variant("llvm_ad_rgb")
x = dr.llvm.Float(np.linspace(0.001, 4.0, 1000, dtype=np.float32))
y = np.array(dr.exp(x) + dr.log(x) + dr.sin(3 * x))
print(json.dumps([llvm_target(), y.tolist()]))
"""


def _child(env: dict[str, str]) -> tuple[list, np.ndarray]:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         env=env, check=True)
    target, values = json.loads(out.stdout.strip().splitlines()[-1])
    return target, np.array(values, np.float32)


def test_the_variable_moves_kernels_to_another_cpu_that_rounds_alike(monkeypatch):
    import os

    env = {k: v for k, v in os.environ.items() if k != LLVM_TARGET_ENV}
    native_target, native = _child(env)
    target, values = _child({**env, LLVM_TARGET_ENV: "haswell"})
    assert target == ["haswell", 8] and native_target != target
    np.testing.assert_allclose(values, native, rtol=1e-6)


@pytest.mark.parametrize("spec, named", [("pentium", "pentium"),
                                         ("haswell:+avx2", "haswell:+avx2"),
                                         ("haswell:+avx2,+fma:5", "vector width '5'")])
def test_a_bad_target_is_refused_naming_the_variable(spec, named):
    with pytest.raises(UsageError, match=rf"\$SPARSE_BRDF_LLVM_TARGET.*{re.escape(named)}"):
        set_llvm_target(spec)


def test_a_command_with_a_bad_target_says_so_in_one_line(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv(LLVM_TARGET_ENV, "pentium")
    line = cli_fails(capsys, "render", "sphere", "-o", tmp_path / "x.exr", "--material",
                     "material=mitsuba:au-ggx-0.25", names=["SPARSE_BRDF_LLVM_TARGET"])
    assert "pentium" in line and not (tmp_path / "x.exr").exists()


def test_the_other_cpu_differs_from_this_one_in_every_library():
    from threadpoolctl import threadpool_info

    from sparse_brdf.mitsuba_env import llvm_target, set_variant

    env = other_cpu()
    assert set(env["NPY_DISABLE_CPU_FEATURES"].split()) >= {"X86_V4", "AVX512_ICL"}
    native_blas = {i.get("architecture") for i in threadpool_info()
                   if i.get("internal_api") == "openblas"}
    if native_blas:
        assert env["OPENBLAS_CORETYPE"] not in native_blas
    set_variant("llvm_ad_rgb")
    cpu, _, width = env[LLVM_TARGET_ENV].split(":")
    assert cpu == LLVM_TARGETS["haswell"][0] and int(width) < llvm_target()[1]


def test_the_pinned_kernels_are_the_ones_a_fresh_process_runs():
    """Under ``other_cpu.py --pinned`` numpy has no AVX-512 kernel, OpenBLAS runs its
    Haswell kernels and Dr.Jit compiles for Haswell at 8 lanes, whatever this CPU is."""
    env = pinned_cpu()
    if env is None:
        pytest.skip("this CPU has no AVX2 and FMA: no kernels to pin")
    probe = ("import json; import numpy as np; from threadpoolctl import threadpool_info; "
             "from sparse_brdf.mitsuba_env import llvm_target, set_variant; "
             "set_variant('llvm_ad_rgb'); "
             "from numpy._core._multiarray_umath import __cpu_dispatch__ as d, "
             "__cpu_features__ as f; "
             "print(json.dumps([[k for k in d if f[k]], "
             "sorted({i.get('architecture') for i in threadpool_info() "
             "if i.get('internal_api') == 'openblas'}), list(llvm_target())]))")
    run = subprocess.run([sys.executable, "-c", probe], env={**os.environ, **env},
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    simd, blas, (cpu, width) = json.loads(run.stdout.splitlines()[-1])
    assert simd and not [k for k in simd if k.startswith(("X86_V4", "AVX512"))], simd
    assert blas in ([], ["Haswell"])
    assert cpu == LLVM_TARGETS["haswell"][0] and width == 8


def test_only_a_cpu_with_avx2_and_fma_gets_pinned_kernels(monkeypatch):
    import other_cpu

    monkeypatch.setattr(other_cpu, "cpu_flags", lambda: {"sse2", "avx"})
    assert other_cpu.pinned_cpu() is None  # the CI bench's gate then widens its tolerances
    monkeypatch.setattr(other_cpu, "cpu_flags", lambda: {"sse2", "avx", "avx2", "fma"})
    env = other_cpu.pinned_cpu()
    assert env["OPENBLAS_CORETYPE"] == "Haswell"
    assert env[LLVM_TARGET_ENV].startswith("haswell:") and env[LLVM_TARGET_ENV].endswith(":8")
