"""Nodal stresses of tetrahedral cells, recovered as Abaqus and CalculiX recover them.

A displacement element's stress lives at its integration points. Commercial and open codes
that users compare with (Abaqus, CalculiX) report nodal values by extrapolating the stress
*tensor* from the integration points to the element's corner nodes, averaging each node's
values over the elements around it (a plain mean), and only then taking invariants such as the
von Mises stress. :class:`NodalStress` does that for the cells given (one body: the average
does not cross into another material), on tetrahedra of any displacement degree: the 4-point
rule of degree 2 (that of a 10-node tetrahedron, C3D10) and the linear extrapolation through
its points.

``recipe = "scalar"`` keeps an earlier recipe for comparison: each cell's von Mises stress
evaluated at its vertices, averaged over the cells around a node weighted by their volumes.
It reads higher than the tensor recipe where the stress turns from cell to cell (the mean of
the von Mises values is at least the von Mises value of the mean tensor).
"""

from __future__ import annotations

import basix
import dolfinx
import dolfinx.fem.petsc as fem_petsc
import numpy as np
import ufl

from shoulder_fem.forms import materials

__all__ = ["RECIPES", "NodalStress", "von_mises_of"]

#: The recipes of :class:`NodalStress`.
RECIPES = ("tensor", "scalar")


def von_mises_of(sigma: np.ndarray) -> np.ndarray:
    """Von Mises stress of stress tensors ``sigma`` (..., 3, 3), symmetric part."""
    s = 0.5 * (sigma + np.swapaxes(sigma, -1, -2))
    dev = s - np.trace(s, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3.0
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", dev, dev))


def _gauss_extrapolation() -> tuple[np.ndarray, np.ndarray]:
    """The degree-2 rule's 4 points (reference) and their extrapolation to the vertices.

    The matrix takes values at the 4 points to the linear function through them, evaluated
    at the vertices.
    """
    pts, _ = basix.make_quadrature(basix.CellType.tetrahedron, 2)
    lam = np.column_stack([1.0 - pts.sum(axis=1), pts])  # (4 points, 4 vertices)
    return pts, np.linalg.inv(lam)


class NodalStress:
    """Nodal stress tensor and von Mises stress of a set of tetrahedra (collective).

    Args:
        mesh: A tetrahedral mesh.
        cells: Local cells of the body (owned and ghost; ghosts are dropped).
        stress: UFL stress tensor (3 x 3, Pa) on ``mesh``.
        recipe: ``"tensor"`` (Abaqus/CalculiX, default) or ``"scalar"`` (module doc).

    Attributes:
        tensor: The nodal stress tensor (P1, 9 components; "tensor" recipe, zero off the body).
        von_mises: The nodal von Mises stress (P1, Pa; zero off the body).
        cells: The body's owned cells.
        cell_dofs: Their P1 dofs (cells, 4), in reference vertex order.
        nodes: The body's owned vertices (P1 dofs).
    """

    def __init__(self, mesh, cells: np.ndarray, stress, recipe: str = "tensor"):
        if recipe not in RECIPES:
            raise ValueError(f"nodal stress recipe {recipe!r}: expected one of {RECIPES}")
        if mesh.topology.cell_type != dolfinx.mesh.CellType.tetrahedron:
            raise ValueError("nodal stress recovery: tetrahedral meshes only")
        self.recipe = recipe
        n_owned = mesh.topology.index_map(3).size_local
        self.cells = np.asarray(cells, dtype=np.int32)[np.asarray(cells) < n_owned]
        self.P = dolfinx.fem.FunctionSpace(mesh, ("Lagrange", 1))
        T = dolfinx.fem.TensorFunctionSpace(mesh, ("Lagrange", 1))
        self.tensor = dolfinx.fem.Function(T, name="stress")
        self.von_mises = dolfinx.fem.Function(self.P, name="von_mises")
        self.cell_dofs = np.array(
            [self.P.dofmap.cell_dofs(c) for c in self.cells], dtype=np.int64
        ).reshape(-1, 4)
        if recipe == "tensor":
            pts, self._extrapolate = _gauss_extrapolation()
            self._expr = dolfinx.fem.Expression(stress, pts)
            weight = np.ones(len(self.cells))
        else:
            D = dolfinx.fem.FunctionSpace(mesh, ("DG", 1))
            self._expr = dolfinx.fem.Expression(
                materials.von_mises(stress), D.element.interpolation_points()
            )
            cell_volume = fem_petsc.assemble_vector(
                dolfinx.fem.form(
                    ufl.TestFunction(dolfinx.fem.FunctionSpace(mesh, ("DG", 0))) * ufl.dx
                )
            )
            weight = cell_volume.array_r[self.cells].copy()
            cell_volume.destroy()
        self._weight = weight
        count = dolfinx.fem.Function(self.P)
        np.add.at(count.x.array, self.cell_dofs, np.repeat(weight, 4).reshape(-1, 4))
        count.x.scatter_reverse(dolfinx.la.ScatterMode.add)
        count.x.scatter_forward()
        self._count = count.x.array.copy()
        n_local = self.P.dofmap.index_map.size_local
        nodes = np.unique(self.cell_dofs)
        self.nodes = nodes[nodes < n_local]

    def _vertex_values(self) -> np.ndarray:
        """Each cell's values at its 4 vertices: (cells, 4, 9) tensors or (cells, 4) scalars."""
        if not len(self.cells):
            return np.zeros((0, 4, 9)) if self.recipe == "tensor" else np.zeros((0, 4))
        vals = np.asarray(self._expr.eval(self.cells))
        if self.recipe == "tensor":
            at_points = vals.reshape(len(self.cells), 4, 9)
            return np.einsum("vg,cgk->cvk", self._extrapolate, at_points)
        return vals.reshape(len(self.cells), 4)

    def update(self) -> dolfinx.fem.Function:
        """Recover at the current state; returns :attr:`von_mises` (collective)."""
        vals = self._vertex_values()
        keep = self._count > 0
        if self.recipe == "tensor":
            total = np.zeros((len(self._count), 9))
            np.add.at(total, self.cell_dofs, vals)
            self.tensor.x.array[:] = total.ravel()
            self.tensor.x.scatter_reverse(dolfinx.la.ScatterMode.add)
            self.tensor.x.scatter_forward()
            arr = self.tensor.x.array.reshape(-1, 9)
            arr[keep] /= self._count[keep, None]
            arr[~keep] = 0.0
            self.von_mises.x.array[:] = von_mises_of(arr.reshape(-1, 3, 3))
        else:
            total = np.zeros(len(self._count))
            np.add.at(total, self.cell_dofs, vals * self._weight[:, None])
            self.von_mises.x.array[:] = total
            self.von_mises.x.scatter_reverse(dolfinx.la.ScatterMode.add)
            self.von_mises.x.scatter_forward()
            arr = self.von_mises.x.array
            arr[keep] /= self._count[keep]
            arr[~keep] = 0.0
        return self.von_mises
