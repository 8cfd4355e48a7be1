#!/usr/bin/env bash
# The GPU checks and figures in one go, on a machine with a CUDA GPU: the kernel tests on the GPU,
# then the benchmarks whose *_cuda.json the README quotes. Each step has its own time limit, so
# one that hangs or fails leaves the others' figures.
#
#     benchmarks/gpu_check.sh OUT [RUN.h5]      # RUN.h5: a propeller run for bench_pipeline --run
set -u
out=${1:?usage: benchmarks/gpu_check.sh OUT [RUN.h5]}
run=${2:-}
python=${PYTHON:-python3}
mkdir -p "$out"
log="$out/gpu_check.log"

step() {  # step SECONDS COMMAND...: run one step under a time limit, its output in the log
    local limit=$1
    shift
    echo "=== $* (limit ${limit} s)" | tee -a "$log"
    local start=$SECONDS
    timeout "$limit" "$@" >>"$log" 2>&1
    echo "=== exit $? after $((SECONDS - start)) s" | tee -a "$log"
}

nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee -a "$log"
step 60 "$python" -c "import warp as wp; wp.init(); print(wp.get_cuda_devices())"
# kernels, maps, CRM and planner against their references, on the GPU (the default device there)
workers=$("$python" -c "import xdist" 2>/dev/null && echo "-n 8")  # pytest-xdist when installed
step 120 "$python" -m pytest -q -x -p no:cacheprovider $workers tests/test_kernels_integration.py \
    tests/test_kernels_queries.py tests/test_kernels_accumulation.py tests/test_integration.py \
    tests/test_globalmap.py tests/test_queries.py tests/test_crm.py tests/test_planner.py tests/test_slam_device.py
# the open questions first (the budget may end the run): the CRM's sorted path (revert it if it
# is not faster than the per-scan sort's 23-41x the VoxelMap), the SLAM front end on the device
step 60 "$python" benchmarks/bench_crm.py --out "$out" --part 3d --quick --device cuda:0
step 120 "$python" benchmarks/bench_slam.py --out "$out" --device cuda:0
step 90 "$python" benchmarks/bench_voxelmap.py --out "$out" --device cuda:0 --scans 10000 --repeats 3
step 90 "$python" benchmarks/bench_globalmap.py --out "$out" --device cuda:0 --repeats 3
step 60 "$python" benchmarks/bench_profile.py --out "$out" --device cuda:0 --repeats 3
step 180 "$python" benchmarks/bench_pipeline.py --out "$out" ${run:+--run "$run"}
step 90 "$python" benchmarks/bench_profile.py --out "$out" --device cuda:0 --repeats 3 --scans 10000 \
    --pass-sweep 256,512,1024,2048,4096
