"""The confidence-rich map: occupancy with a variance, and paths costed by it.

The same sonar scans of the `tank` scene go into a `ConfidenceMap` and a log-odds `VoxelMap`.
Both are scored against the scene's ground truth; then two candidate paths are costed by the
confidence-rich map's mean plus variance (Agha-mohammadi, Eqs. 31-34).
"""

import numpy as np

import vogjax as vj
from vogjax import scenes
from vogjax.io.dataset import Dataset
from vogjax.maps.confidence_cost import edge_risk, inconsistency
from vogjax.sim import simulate_run

simulate_run("tank", "tank.h5", num_scans=300, progress=False, overwrite=True)
with Dataset("tank.h5") as run:
    batch = next(run.batches(len(run)))
# true poses: mapping alone; every beam but those within the sonar's blind distance
origins, points, scan_index = batch.beams(batch.pose_truth, max_range_m=11.0)

crm = vj.ConfidenceMap(vj.CrmConfig(voxel_size=0.1, max_range=11.0, range_sigma_m=0.05))
crm.integrate_scans(origins, points, scan_index)
log_odds = vj.VoxelMap(vj.MapConfig(voxel_size=0.1, max_range=11.0))
log_odds.integrate_scans(origins, points, scan_index)

# score both on the voxels both observed, against the scene's voxel labels
truth = scenes.load("tank").occupancy(0.1)
water, surface = truth.centres(scenes.FREE), truth.centres(scenes.OCCUPIED)
centres = np.concatenate([water, surface])
level = np.r_[np.zeros(len(water)), np.ones(len(surface))]  # the true occupancy level
seen = log_odds.log_odds(centres) != 0  # 0.0: never observed
centres, level = centres[seen], level[seen]
mean, variance = crm.mean(centres), crm.variance(centres)
p = log_odds.probability(centres).astype(np.float64)
print(f"{len(centres)} voxels of water and surface observed")
print(f"mean |error|: confidence-rich {np.mean(np.abs(mean - level)):.3f}, log-odds {np.mean(np.abs(p - level)):.3f}")
print(
    f"inconsistency I_c per voxel: confidence-rich {inconsistency(mean, variance, level) / seen.sum():.4f}, "
    f"log-odds {inconsistency(p, p * (1 - p), level) / seen.sum():.4f}"
)

# cost two 3 m paths from the vehicle's last position: one through water it saw, one into the unknown
start = batch.pose_truth[-1, :3, 3]
ahead = batch.pose_truth[-1, :3, 0]  # the vehicle's forward axis
starts = np.stack([start, start])
ends = np.stack([start + 3.0 * ahead, start - 3.0 * ahead])
risk = edge_risk(crm, starts, ends)
print(f"risk ahead (seen) {risk[0]:.1f}, behind (unseen) {risk[1]:.1f}: summed mean + variance per voxel")
