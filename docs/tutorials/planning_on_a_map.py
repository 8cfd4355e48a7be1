"""Planning on a map: batched ray casts and one next-best-view plan.

A short survey of the `tank` scene is mapped with loop closures; a planner then asks the
online global map what 100,000 rays from the vehicle see, and where the next best view is.
"""

import time

import numpy as np

import vogjax as vj
from vogjax import planner, scenes
from vogjax.sensors import ProfilingSonar
from vogjax.sim import simulate_run

simulate_run("tank", "tank.h5", num_scans=600, progress=False, overwrite=True)
result = vj.pipeline.run("tank.h5", vj.PipelineConfig(), progress=False)
global_map = result.global_map  # the online global map, as the planner would query it
T_world_vehicle = result.scan_poses("optimized")[-1]  # where the vehicle believes it is now

# 100k rays of 4 m from the vehicle in random directions: one batched call
rng = np.random.default_rng(0)
directions = rng.normal(size=(100_000, 3))
origins = np.repeat(T_world_vehicle[None, :3, 3], len(directions), axis=0)
global_map.raycast(origins[:10], directions[:10], 4.0)  # the first call compiles the kernels
start = time.perf_counter()
rays = global_map.raycast(origins, directions, max_range=4.0)
seconds = time.perf_counter() - start
print(f"100k rays in {seconds * 1e3:.0f} ms: {rays.hit.mean():.0%} hit a surface within 4 m,")
print(f"  {rays.num_unknown.mean():.1f} unknown and {rays.num_free.mean():.1f} free voxels before it on average")

# the papers' next-best-view planner: a tree of candidate views, gain counted along its edges
scene = scenes.load("tank")
nbv = planner.NbvPlanner(
    planner.PlannerConfig(seed=0), bounds=scene.bounds, sensor=ProfilingSonar(), region=scene.region()
)
plan = nbv.plan(global_map, T_world_vehicle)
if len(plan.waypoints):
    x, y, z, yaw = plan.waypoints[0]
    print(
        f"next view: x {x:.2f} m, y {y:.2f} m, z {z:.2f} m, yaw {np.degrees(yaw):.0f} deg, "
        f"{plan.gain_m3:.1f} m^3 of unknown volume to see ({plan.nodes} nodes, {plan.rays} gain rays)"
    )
else:
    print(f"no view gains anything: the map is explored ({plan.nodes} nodes)")
