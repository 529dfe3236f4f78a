"""CT-like density: phantom, NIfTI round trip, trilinear mapping to nodes, E(rho)."""

from __future__ import annotations

import dolfinx
import numpy as np
import pytest
from mpi4py import MPI

from shoulder_fem.io import ct as D


def _box_mesh(comm):
    return dolfinx.mesh.create_box(
        comm, [np.array([0.0, 0.0, 0.0]), np.array([0.04, 0.03, 0.02])], [4, 3, 2]
    )


def _image(values_fn, shape=(23, 18, 13), voxel=2.0e-3, origin=(-0.002, -0.002, -0.002)):
    affine = np.eye(4)
    affine[:3, :3] *= voxel
    affine[:3, 3] = origin
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1)
    pts = idx.reshape(-1, 3) * voxel + np.asarray(origin)
    return D.CTImage(values_fn(pts).reshape(shape), affine)


@pytest.mark.mpi
def test_uniform_image_gives_uniform_modulus(comm_tmp):
    """A uniform image: the same modulus at every node to round-off (trilinear weights sum to 1
    to round-off), E0 (rho/rho0)^2 of its calibrated density."""
    comm = MPI.COMM_WORLD
    cal = D.Calibration()
    hu = float(cal.hounsfield(np.array([900.0]))[0])  # 0.9 g/cm^3
    image = _image(lambda p: np.full(len(p), hu))
    path = comm_tmp / "uniform.nii.gz"
    if comm.rank == 0:
        D.write_nifti(image, path)
    comm.Barrier()
    read = D.read_ct(path)
    np.testing.assert_allclose(read.affine, image.affine, rtol=0, atol=1e-12)
    rho, e = D.nodal_modulus(_box_mesh(comm), read, cal)
    expected = float(D.modulus_from_density(np.array([cal.density(float(np.float32(hu)))]))[0])
    np.testing.assert_allclose(e.x.array, expected, rtol=1e-12)  # the float32 HU, calibrated
    np.testing.assert_allclose(rho.x.array, rho.x.array[0], rtol=1e-13)
    # E0 (rho/rho0)^2 with rho = 900: 15 GPa / 4
    assert expected == pytest.approx(15e9 / 4, rel=1e-6)


@pytest.mark.mpi
def test_linear_gradient_is_reproduced_at_the_nodes(comm_tmp):
    comm = MPI.COMM_WORLD
    cal = D.Calibration(intercept=1000.0, slope=0.8)

    def rho(p):  # kg/m^3, linear in x, y, z
        return 500.0 + 2.0e4 * p[:, 0] - 1.0e4 * p[:, 1] + 5.0e3 * p[:, 2]

    image = _image(lambda p: cal.hounsfield(rho(p)))
    path = comm_tmp / "gradient.nii"
    if comm.rank == 0:
        D.write_nifti(image, path)
    comm.Barrier()
    mesh = _box_mesh(comm)
    r, e = D.nodal_modulus(mesh, D.read_ct(path), cal)
    x = r.function_space.tabulate_dof_coordinates()
    # float32 storage of HU: relative error ~1e-7
    np.testing.assert_allclose(r.x.array, rho(x), rtol=1e-5)
    np.testing.assert_allclose(e.x.array, 15e9 * (rho(x) / 1800.0) ** 2, rtol=1e-4)


def test_modulus_floor_and_bad_calibration():
    assert D.modulus_from_density(np.array([0.0]))[0] == D.E_FLOOR
    with pytest.raises(ValueError, match="slope"):
        D.Calibration(slope=0.0)
    with pytest.raises(ValueError, match="floor"):
        D.modulus_from_density(np.array([1.0]), floor=0.0)


def test_shoulder_phantom_has_cortex_and_cancellous_gradient():
    from shoulder_fem.meshes.shoulder import ShoulderGeometry

    g = ShoulderGeometry()
    image = D.shoulder_phantom(g, voxel=1.5e-3)
    cal = D.Calibration()
    rb = g.humeral_bone_radius
    # Along the head axis (+x from the centre, away from the glenoid side): cortex near the
    # surface, cancellous inside, soft tissue outside.
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, rb - 0.5e-3], [0.0, 0.0, rb + 4e-3]])
    rho = D.nodal_density(image, pts, cal)
    assert 300.0 <= rho[0] <= 600.0
    assert rho[1] > 1400.0
    assert abs(rho[2] - D.PHANTOM_SOFT_TISSUE_DENSITY) < 50.0
    # The cancellous gradient: denser near the joint than 60 mm down the blade.
    deep = D.nodal_density(image, np.array([[-0.09, 0.0, -0.01]]), cal)[0]
    assert deep < rho[0] or deep > 1400.0


def test_phantom_image_is_the_same_slab_by_slab():
    """The image built a few slabs at a time (bounded work arrays) is, voxel for voxel, the one
    built in a single pass over the grid; a slab below one plane still makes whole planes."""
    ball = 0.02

    def depth(p):
        return ball - np.linalg.norm(p, axis=1)

    args = (lambda p: depth(p) > 0.0, depth, np.full(3, -0.025), np.full(3, 0.025))
    whole = D.phantom_image(*args, voxel=1e-3, slab_voxels=10**9)
    for slab in (1, 2_000, 51 * 51 * 3 + 7):
        part = D.phantom_image(*args, voxel=1e-3, slab_voxels=slab)
        assert np.array_equal(part.hu, whole.hu), slab
        assert np.array_equal(part.affine, whole.affine)
    assert whole.hu.shape == (51, 51, 51)


def test_dicom_series_round_trip(tmp_path):
    pydicom = pytest.importorskip("pydicom")
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    hu = np.arange(4 * 3 * 5, dtype=float).reshape(4, 3, 5) * 10 - 200
    for k in range(hu.shape[2]):
        meta = FileMetaDataset()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.2"
        meta.MediaStorageSOPInstanceUID = generate_uid()
        ds = FileDataset(str(tmp_path / f"s{k}.dcm"), {}, file_meta=meta, preamble=b"\0" * 128)
        ds.Rows, ds.Columns = hu.shape[:2]
        ds.PixelSpacing = [0.5, 0.7]
        ds.ImageOrientationPatient = [1, 0, 0, 0, 1, 0]
        ds.ImagePositionPatient = [0.0, 0.0, 2.0 * (4 - k)]  # files out of order on purpose
        ds.RescaleSlope, ds.RescaleIntercept = 1.0, -1024.0
        ds.BitsAllocated, ds.BitsStored, ds.HighBit = 16, 16, 15
        ds.PixelRepresentation, ds.SamplesPerPixel = 0, 1
        ds.PhotometricInterpretation = "MONOCHROME2"
        ds.PixelData = (hu[:, :, 4 - k] + 1024).astype(np.uint16).tobytes()
        ds.is_little_endian, ds.is_implicit_VR = True, False
        ds.save_as(str(tmp_path / f"s{k}.dcm"))
    del pydicom
    image = D.read_ct(tmp_path)
    np.testing.assert_allclose(image.hu, hu)
    np.testing.assert_allclose(image.affine[:3, 2], [0, 0, 2e-3])


def test_scan_check_of_no_point_says_nothing(caplog):
    """A mesh variant without bone volumes (the rigid-bone one) has no node to check: no
    warning (it used to warn of a uniform density of -inf kg/m^3); a uniform image over real
    points still warns, by the density it has (the calibration of its HU, by hand)."""
    image = D.CTImage(np.full((4, 4, 4), 300.0), np.eye(4) * 1e-3 + np.diag([0, 0, 0, 1 - 1e-3]))
    with caplog.at_level("WARNING", logger=D.__name__):
        D.check_scan(image, np.zeros((0, 3)), MPI.COMM_SELF, "scan")
    assert caplog.text == ""
    with caplog.at_level("WARNING", logger=D.__name__):
        D.check_scan(image, np.full((5, 3), 1e-3), MPI.COMM_SELF, "scan", D.Calibration())
    assert f"uniform ({131.7 + 1.169 * 300:.6g} kg/m^3)" in caplog.text
