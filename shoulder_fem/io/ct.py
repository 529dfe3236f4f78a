"""Bone density from CT, as the paper took it: CT reader, CT-like phantom, nodal density, E(rho).

The paper computed the bone density at every node from CT images and the modulus from it,
E = E0 (rho / rho0)^2 (paper, Table I: E0 = 15 GPa, rho0 = 1.8 g/cm^3). With no CT of the
paper's shoulder, :func:`shoulder_phantom` makes a CT-like image of the parametric bones
(:func:`phantom_image`); a real CT (NIfTI, or a DICOM series) goes through the same
:func:`read_ct` / :func:`nodal_density` path. Images hold Hounsfield units with a linear
calibration (:class:`Calibration`); units are SI in code (kg/m^3, Pa, m), mm in NIfTI files.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shoulder_fem.forms.materials import bone_modulus

#: Cortical bone apparent density (kg/m^3): ~1.8 g/cm^3 (paper's rho0; Hayes 1991 range).
CORTICAL_DENSITY = 1800.0
#: Cancellous density range (kg/m^3), 0.3-0.6 g/cm^3 (Morgan et al. 2003 ranges, ANATOMY.md).
CANCELLOUS_RANGE = (300.0, 600.0)
#: The phantom's density around the bones (kg/m^3): 1000, the mass density of soft tissue.
#: It is not what a scan holds there (soft tissue is about 0 HU, 132 kg/m^3 of apparent bone
#: density with the default calibration), but the bone nodes on the surface take part of it
#: (trilinear sampling across the boundary voxel): measured at coarse, 0 HU there made the
#: scapula's peak von Mises stress 30 % higher (3.79 against 2.90 MPa at 60 deg), the
#: decoupling's subscapularis difference 1.5 % (0.95 %) and the coupled run cut one step back.
#: A model change of that size waits for the whole-model study (issue 20); until then the
#: phantom keeps the density of before, whatever the calibration that stores it in HU.
PHANTOM_SOFT_TISSUE_DENSITY = 1000.0
#: Floor on the modulus (Pa) so that marrow / low-density voxels do not give a singular matrix.
E_FLOOR = 10.0e6


@dataclass(frozen=True)
class Calibration:
    """Linear HU -> apparent bone density calibration, rho = intercept + slope * HU (kg/m^3).

    The default chains the usual QCT steps: an equivalent mineral density of about 0.8 mg/cm^3
    per HU (a K2HPO4 phantom; scanner-specific), the ash density 0.877 rho_QCT + 0.079 g/cm^3
    (Keyak et al. 1994) and the apparent density ash / 0.6 (Keyak 1994; Schileo et al. 2008):
    rho_app = 131.7 + 1.169 HU kg/m^3. So water and soft tissue (0 HU) read 132 kg/m^3 (E =
    E0 (rho/rho0)^2 = 80 MPa: no bone), cancellous bone (100-400 HU) 250-600 kg/m^3 and
    cortical bone (1400-1500 HU) 1.8-1.9 g/cm^3, the paper's rho0. The calibration of before
    (rho = 1000 + 0.8 HU: 0 HU at 1000 kg/m^3, i.e. E = 4.6 GPa for marrow or soft tissue)
    made cancellous bone from a real scan 10-20 times too stiff. A real scan should use the
    calibration of its own density phantom (scene keys ``ct_density_intercept``,
    ``ct_density_slope``).
    """

    intercept: float = 131.7
    slope: float = 1.169

    def __post_init__(self) -> None:
        if not self.slope > 0 or not math.isfinite(self.intercept):
            raise ValueError(
                f"calibration slope = {self.slope} kg/m^3/HU must be > 0 and intercept = "
                f"{self.intercept} kg/m^3 finite"
            )

    def density(self, hu: np.ndarray) -> np.ndarray:
        """Apparent density (kg/m^3) from Hounsfield units, clipped at 0."""
        return np.maximum(self.intercept + self.slope * np.asarray(hu, dtype=float), 0.0)

    def hounsfield(self, rho: np.ndarray) -> np.ndarray:
        """Hounsfield units for apparent density ``rho`` (kg/m^3)."""
        return (np.asarray(rho, dtype=float) - self.intercept) / self.slope


@dataclass(frozen=True)
class CTImage:
    """A CT volume in Hounsfield units and its affine.

    Attributes:
        hu: array (ni, nj, nk) of Hounsfield units.
        affine: 4 x 4 matrix, voxel index (i, j, k, 1) -> position (m) in the model frame.
    """

    hu: np.ndarray
    affine: np.ndarray


def phantom_image(
    inside_bone: Callable[[np.ndarray], np.ndarray],
    distance_to_surface: Callable[[np.ndarray], np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    voxel: float = 1.0e-3,
    joint_centre: np.ndarray | None = None,
    cortical_thickness: float = 2.0e-3,
    calibration: Calibration | None = None,
    slab_voxels: int = 250_000,
) -> CTImage:
    """A CT-like image of bone (HU) on a box grid.

    Density: ``CORTICAL_DENSITY`` within ``cortical_thickness`` of the bone surface; inside, a
    cancellous density falling linearly from 0.6 g/cm^3 near ``joint_centre`` to 0.3 g/cm^3 at
    100 mm from it; outside the bone, :data:`PHANTOM_SOFT_TISSUE_DENSITY`. The cortex is blended
    over one voxel to avoid a staircase.

    Args:
        inside_bone: points (n, 3) in m -> boolean mask.
        distance_to_surface: points (n, 3) in m -> distance (m) to the bone surface (inside).
        lower: lower corner of the image box (m).
        upper: upper corner (m).
        voxel: voxel size (m).
        joint_centre: centre of the density gradient (m); default the box centre.
        cortical_thickness: cortical shell thickness (m), ~2 mm.
        calibration: HU calibration used to store densities.
        slab_voxels: voxels evaluated at once (whole slabs of the first axis, at least one):
            bounds the work arrays; the image does not depend on it.
    """
    cal = calibration or Calibration()
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    shape = np.maximum(np.ceil((upper - lower) / voxel).astype(int) + 1, 2)
    axes = [lower[d] + voxel * np.arange(shape[d]) for d in range(3)]
    centre = 0.5 * (lower + upper) if joint_centre is None else np.asarray(joint_centre)
    lo, hi = CANCELLOUS_RANGE
    soft = PHANTOM_SOFT_TISSUE_DENSITY
    hu = np.empty(tuple(shape))
    # Slab by slab along the first axis: the voxel values are the same, the peak memory is that
    # of the image plus one slab's work arrays (a whole-grid pass took ~450 MB at 1 mm voxels).
    step = max(1, int(slab_voxels) // int(shape[1] * shape[2]))
    for i0 in range(0, shape[0], step):
        sub = [axes[0][i0 : i0 + step], axes[1], axes[2]]
        grid = np.stack(np.meshgrid(*sub, indexing="ij"), axis=-1).reshape(-1, 3)
        inside = inside_bone(grid)
        rho = np.full(len(grid), soft)
        r = np.linalg.norm(grid - centre, axis=1)
        cancellous = hi - (hi - lo) * np.clip(r / 0.1, 0.0, 1.0)
        depth = np.zeros(len(grid))
        depth[inside] = distance_to_surface(grid[inside])
        w = np.clip((cortical_thickness - depth) / voxel + 0.5, 0.0, 1.0)  # 1 in the cortex
        rho[inside] = (w * CORTICAL_DENSITY + (1 - w) * cancellous)[inside]
        hu[i0 : i0 + step] = cal.hounsfield(rho).reshape(len(sub[0]), shape[1], shape[2])
    affine = np.eye(4)
    affine[:3, :3] *= voxel
    affine[:3, 3] = lower
    return CTImage(hu, affine)


def write_nifti(image: CTImage, path: str | Path) -> Path:
    """Write ``image`` as NIfTI-1 (HU as float32) with its affine converted to mm."""
    import nibabel

    affine_mm = image.affine.copy()
    affine_mm[:3, :] *= 1e3
    img = nibabel.Nifti1Image(np.asarray(image.hu, dtype=np.float32), affine_mm)
    img.header.set_xyzt_units("mm")
    path = Path(path)
    nibabel.save(img, str(path))
    return path


def read_ct(path: str | Path) -> CTImage:
    """Read a CT volume: a NIfTI file (.nii, .nii.gz) or a folder holding a DICOM series.

    NIfTI data are taken as HU after the header's scaling (nibabel applies scl_slope/inter);
    the affine (mm) is converted to m. A DICOM series is sorted along the slice normal and its
    RescaleSlope/Intercept applied.

    Raises:
        ValueError: if the file is not readable as CT or is not 3D.
    """
    path = Path(path)
    if path.is_dir():
        return _read_dicom_series(path)
    import nibabel

    try:
        img = nibabel.load(str(path))
        data = np.asarray(img.get_fdata(), dtype=float)
    except Exception as err:  # noqa: BLE001 - nibabel raises many kinds
        raise ValueError(f"{path}: not a readable NIfTI image ({err})") from None
    if data.ndim == 4 and data.shape[3] == 1:
        data = data[..., 0]
    if data.ndim != 3:
        raise ValueError(f"{path}: expected a 3D image, got shape {data.shape}")
    affine = np.asarray(img.affine, dtype=float).copy()
    affine[:3, :] *= 1e-3
    return CTImage(data, affine)


def _read_dicom_series(folder: Path) -> CTImage:
    try:
        import pydicom
    except ImportError:  # pragma: no cover - pydicom comes with the project's setup
        raise ValueError(f"{folder}: reading DICOM needs pydicom (python3-pydicom)") from None
    slices = []
    for f in sorted(folder.iterdir()):
        try:
            ds = pydicom.dcmread(str(f))
        except Exception:  # noqa: BLE001 - skip non-DICOM files
            continue
        if hasattr(ds, "ImagePositionPatient") and hasattr(ds, "pixel_array"):
            slices.append(ds)
    if len(slices) < 2:
        raise ValueError(f"{folder}: fewer than 2 DICOM slices found")
    orient = np.asarray(slices[0].ImageOrientationPatient, dtype=float)
    row, col = orient[:3], orient[3:]
    normal = np.cross(row, col)
    slices.sort(key=lambda ds: float(np.dot(normal, np.asarray(ds.ImagePositionPatient, float))))
    origin = np.asarray(slices[0].ImagePositionPatient, dtype=float)
    step = np.asarray(slices[1].ImagePositionPatient, dtype=float) - origin
    dr, dc = (float(v) for v in slices[0].PixelSpacing)
    hu = np.stack(
        [
            ds.pixel_array.astype(float) * float(getattr(ds, "RescaleSlope", 1.0))
            + float(getattr(ds, "RescaleIntercept", 0.0))
            for ds in slices
        ],
        axis=-1,
    )  # (rows, cols, slices)
    affine = np.eye(4)
    affine[:3, 0] = col * dr  # along rows index (i): moves down a column
    affine[:3, 1] = row * dc
    affine[:3, 2] = step
    affine[:3, 3] = origin
    affine[:3, :] *= 1e-3
    return CTImage(hu, affine)


def sample_trilinear(image: CTImage, points: np.ndarray) -> np.ndarray:
    """HU at ``points`` (n, 3, in m) by trilinear interpolation of the voxel values.

    Points outside the image take the value at the nearest point of the image (clamped).
    """
    shape = np.array(image.hu.shape)
    ijk = np.clip(_voxel_coordinates(image, points), 0.0, shape - 1.0)
    i0 = np.minimum(np.floor(ijk).astype(int), shape - 2)
    f = ijk - i0
    out = np.zeros(len(points))
    for corner in range(8):
        o = np.array([(corner >> d) & 1 for d in range(3)])
        w = np.prod(np.where(o == 1, f, 1.0 - f), axis=1)
        idx = i0 + o
        out += w * image.hu[idx[:, 0], idx[:, 1], idx[:, 2]]
    return out


def _voxel_coordinates(image: CTImage, points: np.ndarray) -> np.ndarray:
    """Continuous voxel indices (i, j, k) of ``points`` (n, 3, m), (n, 3)."""
    inv = np.linalg.inv(image.affine)
    return (np.c_[points, np.ones(len(points))] @ inv.T)[:, :3]


def outside_image(image: CTImage, points: np.ndarray) -> np.ndarray:
    """Whether each of ``points`` (n, 3, m) lies outside the image's voxel grid (n,) bool."""
    ijk = _voxel_coordinates(image, points)
    shape = np.array(image.hu.shape)
    tol = 1e-9
    return np.any((ijk < -tol) | (ijk > shape - 1.0 + tol), axis=1)


def image_box(image: CTImage) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper corners (m) of the image's voxel centres in the model frame."""
    shape = np.array(image.hu.shape) - 1
    corners = np.array(
        [[i, j, k, 1] for i in (0, shape[0]) for j in (0, shape[1]) for k in (0, shape[2])]
    )
    xyz = (corners @ image.affine.T)[:, :3]
    return xyz.min(axis=0), xyz.max(axis=0)


#: A CT image whose voxel grid misses more than this fraction of the mesh's nodes is refused
#: (their values would be the clamped border's, not the bone's).
MAX_OUTSIDE = 0.5


def check_coverage(image: CTImage, points: np.ndarray, comm, source) -> float:
    """The fraction of the mesh's nodes outside ``image`` (collective).

    Beyond :data:`MAX_OUTSIDE`, a ValueError that says where the image and the mesh lie.
    ``points``: this rank's owned nodes (n, 3, m); ``source``: the image's name in the message.
    """
    from mpi4py import MPI

    outside = outside_image(image, points)
    counts = comm.allreduce(np.array([np.count_nonzero(outside), len(outside)]))
    fraction = counts[0] / max(counts[1], 1)
    if fraction > MAX_OUTSIDE:
        lo, hi = image_box(image)
        big = np.full(3, np.inf)
        box = comm.allreduce(
            np.r_[points.min(axis=0), -points.max(axis=0)] if len(points) else np.r_[big, big],
            op=MPI.MIN,
        )
        raise ValueError(
            f"{source}: {100 * fraction:.0f} % of the mesh's nodes lie outside the image "
            f"(image from {_mm(lo)} to {_mm(hi)} mm, mesh from {_mm(box[:3])} to "
            f"{_mm(-box[3:])} mm): is it the model's scan, in the model's frame?"
        )
    return float(fraction)


def check_scan(
    image: CTImage, points: np.ndarray, comm, source: str, calibration: Calibration | None = None
) -> None:
    """Check a scan for the bones at ``points`` (this rank's, (n, 3), m; collective).

    Refused with a ValueError when it misses more than :data:`MAX_OUTSIDE` of them
    (:func:`check_coverage`); a warning when it misses some, or when its density is the same
    at all of them.
    """
    import logging

    from mpi4py import MPI

    log = logging.getLogger(__name__)
    fraction = check_coverage(image, points, comm, source)
    if fraction > 0 and comm.rank == 0:
        log.warning(
            "%s: %.1f %% of the mesh's nodes lie outside the image (values clamped to its border)",
            source,
            100 * fraction,
        )
    rho = nodal_density(image, points, calibration)
    lo = comm.allreduce(float(rho.min(initial=np.inf)), op=MPI.MIN)
    hi = comm.allreduce(float(rho.max(initial=-np.inf)), op=MPI.MAX)
    if lo > hi:  # no point on any rank (a mesh variant without bone volumes)
        return
    if hi - lo <= 1e-9 * max(abs(hi), 1.0) and comm.rank == 0:
        log.warning("%s: the density is uniform (%.6g kg/m^3) over the mesh", source, hi)


def _mm(xyz) -> str:
    return "(" + ", ".join(f"{1e3 * v:.0f}" for v in xyz) + ")"


def nodal_density(
    image: CTImage, points: np.ndarray, calibration: Calibration | None = None
) -> np.ndarray:
    """Apparent density (kg/m^3) at mesh nodes ``points`` (n, 3, m): trilinear HU, calibrated."""
    return (calibration or Calibration()).density(sample_trilinear(image, points))


def modulus_from_density(
    rho: np.ndarray, e0: float = 15.0e9, rho0: float = 1800.0, floor: float = E_FLOOR
) -> np.ndarray:
    """E = max(E0 (rho / rho0)^2, floor) in Pa (paper, Table I; floor avoids E = 0 in marrow)."""
    if not floor > 0:
        raise ValueError(f"modulus floor = {floor} Pa must be > 0")
    return np.maximum(bone_modulus(np.asarray(rho, dtype=float), e0, rho0), floor)


def nodal_modulus(
    mesh, image: CTImage, calibration: Calibration | None = None, floor: float = E_FLOOR
):
    """P1 functions of density (kg/m^3) and modulus (Pa) on ``mesh`` from a CT image.

    Every rank samples its own nodes (owned and ghost): no communication needed.

    Returns:
        (rho, E) as dolfinx P1 Functions.
    """
    import dolfinx

    space = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
    points = space.tabulate_dof_coordinates()
    rho = dolfinx.fem.Function(space, name="density")
    rho.x.array[:] = nodal_density(image, points, calibration)
    e = dolfinx.fem.Function(space, name="youngs_modulus")
    e.x.array[:] = modulus_from_density(rho.x.array, floor=floor)
    return rho, e


def shoulder_phantom(
    geometry, voxel: float = 1.0e-3, margin: float = 5.0e-3, calibration: Calibration | None = None
) -> CTImage:
    """CT-like phantom of the parametric humeral head and glenoid/scapular neck region.

    Bone is described implicitly, following the builder's shapes (:class:`_ShoulderBones`); the
    gradient centre is the joint. The image covers both bones; outside it, values are clamped to
    the nearest voxel.

    Args:
        geometry: a :class:`shoulder_fem.meshes.shoulder.ShoulderGeometry`.
        voxel: voxel size (m).
        margin: extra space around the bones (m).
        calibration: HU calibration.
    """
    bones = _ShoulderBones(geometry)
    lay, rb = bones.layout, bones.rb
    distal = np.asarray(lay.distal[0]) * 1e-3
    reach = geometry.shaft_radius + margin
    lower = np.minimum(np.array([bones.x_med, -rb, bones.z_bot]) - margin, distal - reach)
    upper = np.maximum(np.array([rb, rb, bones.z_top]) + margin, distal + reach)
    return phantom_image(
        lambda p: bones.depth(p) > 0.0,
        bones.depth,
        lower,
        upper,
        voxel=voxel,
        joint_centre=np.zeros(3),
        calibration=calibration,
    )


def _ellipse_depth(u: np.ndarray, v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Approximate depth inside the ellipse (u/a)^2 + (v/b)^2 <= 1 (m, > 0 inside)."""
    return np.minimum(a, b) * (1.0 - np.sqrt((u / a) ** 2 + (v / b) ** 2))


class _ShoulderBones:
    """The parametric bones as an implicit shape: depth (m) below their surface, > 0 inside.

    Five parts, following the builder's shapes: the subchondral humeral sphere, the
    metaphysis/shaft as a capsule around the shaft axis, the blade (tapered slab), the neck
    (elliptic sections from the blade to the glenoid oval) and the glenoid plate hollowed by the
    subchondral glenoid sphere. Each part reaches a few mm into the next, so that their junctions
    are no surface. Lengths in m, in the model frame.
    """

    def __init__(self, geometry) -> None:
        from shoulder_fem.meshes import shoulder

        self.geometry = geometry
        self.layout = lay = shoulder.layout(geometry)
        self.blade_half_thickness = functools.partial(shoulder.blade_half_thickness, geometry)
        self.rb = geometry.subchondral_radius
        s_dir, s_base = shoulder.shaft_axis(geometry)
        self.s_dir = lay.rot @ s_dir
        self.s_base = lay.rot @ (s_base + geometry.humeral_shift) * 1e-3
        self.x_med = lay.x_med * 1e-3
        self.z_top, self.z_bot = lay.z_top * 1e-3, lay.z_bot * 1e-3
        cg = lay.rot @ np.array(
            [geometry.glenoid_radius - geometry.articular_radius - geometry.contact_offset, 0, 0]
        )
        self.r_sub = geometry.glenoid_radius + geometry.glenoid_cartilage_thickness
        self.x_lat = lay.x_lat * 1e-3
        self.px0, self.px1 = (v * 1e-3 for v in lay.plate_x)  # glenoid plate's x range
        self.cg_g = lay.rot.T @ cg  # subchondral glenoid sphere's centre (glenoid frame)

    def humerus(self, p: np.ndarray) -> list[np.ndarray]:
        """Depths in the head sphere and in the shaft's capsule, points ``p`` (n, 3)."""
        geometry = self.geometry
        head = self.rb - np.linalg.norm(p, axis=1)
        t = np.clip((p - self.s_base) @ self.s_dir, 0.0, geometry.shaft_length)
        radial = np.linalg.norm(p - self.s_base - t[:, None] * self.s_dir, axis=1)
        shaft = geometry.shaft_radius - radial
        return [head, shaft]

    def blade(self, p: np.ndarray) -> np.ndarray:
        """Depth in the scapular blade, a tapered slab."""
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        half = self.blade_half_thickness(x * 1e3) * 1e-3
        return np.minimum.reduce(
            [
                half - np.abs(y),
                z - self.z_bot,
                self.z_top - z,
                x - self.x_med,
                self.x_lat + 4e-3 - x,
            ]
        )

    def neck(self, p: np.ndarray) -> np.ndarray:
        """Depth in the neck: elliptic sections from the blade's junction to the glenoid oval."""
        geometry, x_lat, px0 = self.geometry, self.x_lat, self.px0
        x, y, z = p[:, 0], p[:, 1], p[:, 2]
        f = np.clip((x - x_lat) / (px0 - x_lat), 0.0, 1.0)
        a = (0.35 + 0.15 * f) * geometry.glenoid_height
        b = 0.5 * geometry.blade_thickness_lateral + f * (
            0.5 * geometry.glenoid_width - 0.5 * geometry.blade_thickness_lateral
        )
        return np.minimum.reduce([_ellipse_depth(z, y, a, b), x - (x_lat - 5e-3), px0 + 3e-3 - x])

    def plate(self, p: np.ndarray) -> np.ndarray:
        """Depth in the glenoid plate (glenoid frame), hollowed by the subchondral sphere."""
        height, width = self.geometry.glenoid_height, self.geometry.glenoid_width
        q = p @ self.layout.rot  # rows: rot.T @ p
        return np.minimum.reduce(
            [
                _ellipse_depth(
                    q[:, 2], q[:, 1], np.full(len(q), 0.5 * height), np.full(len(q), 0.5 * width)
                ),
                q[:, 0] - self.px0,
                self.px1 - q[:, 0],
                np.linalg.norm(q - self.cg_g, axis=1) - self.r_sub,
            ]
        )

    def depth(self, p: np.ndarray) -> np.ndarray:
        """Depth (m) below the bone surface at points ``p`` (n, 3, m): the deepest part's."""
        parts = [*self.humerus(p), self.blade(p), self.neck(p), self.plate(p)]
        return np.max(np.stack(parts), axis=0)
