"""A plain driver: root stress of the spinning bar against spin rate (decoupled, steady)."""

import sys

from shoulder_fem import load_scene, run

out = sys.argv[1] if len(sys.argv) > 1 else "results/spin-rate-study"
scene = load_scene("spinning-bar").with_values(quasi_static=True, end_time=0.1, time_step=0.1)
for rate in (25.0, 50.0, 100.0):
    result = run(
        scene.with_values(spin_rate=rate),
        "decoupled",
        level="coarse",
        out=f"{out}/omega-{rate:g}",
        replace=True,  # a rerun of the study replaces its results
    )
    print(f"{rate:6.1f} rad/s  root stress {result.probes['root_axial_stress'] / 1e6:.6f} MPa")
