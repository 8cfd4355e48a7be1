"""Every Warp kernel module also builds for a CUDA GPU, checked without one: NVRTC (shipped
with warp-lang) compiles each module to PTX for sm_90, so a construct that only the CUDA code
path rejects fails here, not on the first GPU machine."""

import importlib
import pkgutil

import pytest
import warp as wp

import vogjax.kernels as kernels


def kernel_modules():
    for info in pkgutil.iter_modules(kernels.__path__):
        module = importlib.import_module(f"{kernels.__name__}.{info.name}")
        if any(isinstance(v, wp.Kernel) and v.module.name == module.__name__ for v in vars(module).values()):
            yield info.name


@pytest.mark.parametrize("name", sorted(kernel_modules()))
def test_kernel_module_builds_for_cuda(name, tmp_path):
    wp.init()
    runtime = wp._src.context.runtime
    if 90 not in getattr(runtime, "nvrtc_supported_archs", set()):
        pytest.skip("this Warp build has no NVRTC for sm_90")
    module = importlib.import_module(f"{kernels.__name__}.{name}")
    paths = wp.compile_aot_module(module, arch=90, use_ptx=True, module_dir=tmp_path)
    assert paths and all(p.exists() and p.stat().st_size > 0 for p in paths)
    ptx = paths[0].read_text()
    for kernel in (v for v in vars(module).values() if isinstance(v, wp.Kernel)):
        if kernel.module.name == module.__name__:
            assert kernel.key in ptx  # each kernel has its entry point


@pytest.mark.parametrize("num_bins", [3, 16])
def test_confidence_bins_module_builds_for_cuda(num_bins, tmp_path):
    """The confidence-rich map's kernels over distributions live in one module per bin count
    (kernels.confidence.for_bins), which the module scan above does not see."""
    wp.init()
    runtime = wp._src.context.runtime
    if 90 not in getattr(runtime, "nvrtc_supported_archs", set()):
        pytest.skip("this Warp build has no NVRTC for sm_90")
    from vogjax.kernels import confidence

    bins = confidence.for_bins(num_bins)
    paths = wp.compile_aot_module(bins.integrate_in_order.module, arch=90, use_ptx=True, module_dir=tmp_path)
    ptx = paths[0].read_text()
    for kernel in (v for v in vars(bins).values() if isinstance(v, wp.Kernel)):
        assert kernel.key in ptx
