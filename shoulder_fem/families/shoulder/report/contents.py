"""What the shoulder report names, and how it writes a number.

The figures and their captions, the methods, the motion series and the time split it tabulates,
the rows and columns of its resources table, the unit of its stresses and its number format:
one place for what the metrics, the figures and the tables share.
"""

from __future__ import annotations

import math
from typing import Any

FIGURES = {
    "pressure_maps.png": "Glenoid contact pressure every 10 deg (Fig. 2)",
    "max_pressure.png": "Maximum glenoid pressure against the rotation angle",
    "muscle_forces.png": "Muscle forces against the rotation angle (Fig. 3)",
    "section_von_mises.png": "Von Mises stress in the horizontal section of the scapula (Fig. 4)",
    "von_mises_scatter.png": "Nodal von Mises stress, decoupled against coupled (Fig. 5)",
    "von_mises_error_histogram.png": "Histogram of the nodal von Mises differences (Fig. 5b)",
    "von_mises_by_angle.png": "Nodal von Mises agreement at every output angle",
    "resources.png": "CPU time, peak memory and results disk per method and part",
}
"""The figures :func:`write_report` writes, with their captions."""

METHODS = ("coupled", "decoupled")
"""The methods compared: the coupled run is the reference."""

RESOURCE_COLUMNS = ("coupled", "decoupled_part1", "decoupled_part2", "decoupled")
"""The columns of the resources table (Table II): each method's run, each decoupled part."""

RESOURCE_LABELS = {
    "coupled": "coupled",
    "decoupled_part1": "decoupled part 1",
    "decoupled_part2": "decoupled part 2",
    "decoupled": "decoupled total",
}
"""The label of each column of :data:`RESOURCE_COLUMNS`."""

RESOURCE_ROWS = (
    ("cpu_s", "CPU s", ".1f"),
    ("peak_rss_mb", "peak memory MB", ".0f"),
    ("temp_disk_mb", "temporary disk MB", ".2f"),
    ("results_disk_mb", "results disk MB", ".2f"),
    ("wall_s", "wall s", ".1f"),
    ("ranks", "ranks", "d"),
    ("dofs", "DOFs", "d"),
)
"""The rows of the resources table: (key, label, format spec)."""

MPA = 1e-6
"""Factor from the runs' pascals to the report's megapascals."""

#: The humerus's motion series compared per angle (``<series>_deg`` in ``per_angle``) and
#: their column labels: the swing (and its parts: the shaft's change of elevation and of
#: azimuth about the vertical) and where the glenoid presses on the humeral cartilage.
MOTION_SERIES = (
    ("humeral_swing", "swing"),
    ("humeral_swing_elevation", "elevation change"),
    ("humeral_swing_azimuth", "azimuth change"),
    ("humeral_cap_contact_angle", "contact mean"),
    ("humeral_cap_contact_angle_max", "contact max"),
    ("humeral_cap_edge_margin", "margin to the edge"),
)

#: The glenohumeral contact's penalty compared per angle (``<series>`` in ``per_angle``): the
#: series, its column label, the factor from the runs' SI value and its unit.
CONTACT_SERIES = (
    ("glenohumeral_penetration", "deepest overlap", 1e3, "mm"),
    ("glenohumeral_overlap", "penalty overlap", 1e6, "um"),
    ("glenohumeral_glenoid_layer", "glenoid layer", 1e6, "um"),
    ("glenohumeral_humeral_layer", "humeral layer", 1e6, "um"),
    ("glenohumeral_penalty_share", "penalty share", 1e2, "%"),
    ("glenohumeral_penalty_energy_share", "energy share", 1e2, "%"),
)

#: Where the Newton time went (probes ``<stepping>_time_<key>_s`` of the runs), in table order.
TIME_SPLIT = (
    ("newton", "Newton solves, in all"),
    ("residual", "residual evaluations"),
    ("jacobian", "Jacobian evaluations"),
    ("jacobian_fe_assembly", "of which FE residual and matrix assembly"),
    ("jacobian_reduction", "of which reduction P^T K P (rigid bodies)"),
    ("linear", "linear solves (LU)"),
    ("contact", "contact search and assembly (in residual and Jacobian)"),
)


def fmt(value: Any, spec: str = ".3g") -> str:
    """A number as the report writes it: ``value`` with ``spec``, ``–`` for None/NaN.

    Args:
        value: a number (or None, a bool, anything else: written with ``str``).
        spec: a format spec (``"d"`` rounds to an integer).

    Returns:
        The text.
    """
    if value is None or isinstance(value, bool):
        return "–" if value is None else str(value)
    if isinstance(value, int | float):
        if not math.isfinite(value):
            return "–"
        if spec == "d":
            return f"{int(round(value)):d}"
        return f"{value:{spec}}"
    return str(value)
