"""Tie offsets: a rigid body that carries a surface displaced in its own frame.

A decoupled model's part 1 takes a bone as rigid; its part 2 finds the bone's elastic
displacement in its floating frame. With :meth:`OffsetTies.set_tie_offsets` part 1's rigid body
carries the displaced surface: the tied nodes and the spring ends follow
``x = X_ref + t + R (X + o - X_ref)`` (the prolongation, the tie loads and the springs use the
moved body points), i.e. the body is the deformed bone moved rigidly, with its moments about the
deformed shape.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

__all__ = ["OffsetTies"]


class OffsetTies:
    """The tie-offset method of :class:`~.system.RigidSystem` (a mixin; collective)."""

    def set_tie_offsets(
        self,
        name: str,
        offsets: Callable[[np.ndarray], np.ndarray] | None = None,
        springs: Mapping[str, np.ndarray] | None = None,
    ) -> None:
        """Tie body ``name``'s nodes and spring ends at points moved in the body's frame.

        A tied node with reference position X then follows ``x = X_ref + t + R (X + o - X_ref)``
        and a spring end at P is at ``X_ref + t + R (P + o_P - X_ref)``: the body carries a
        surface displaced by ``o`` in its own frame (e.g. an elastic deformation found by
        another model, decoupled part 2). The motion (t, R) is not changed; the tied nodes
        move to their new places at the next solve. Calling again replaces every offset.

        Args:
            name: The body.
            offsets: Callable(X) -> o: the offsets (m, (n, 3), body frame) of the local tied
                nodes whose reference positions (m) are the rows of X; ``None``: no offsets.
            springs: ``{spring name: o_P}`` (m, body frame) for spring ends on this body; the
                others are at their points.

        Raises:
            ValueError: ``linear_ties``, an unknown body or spring (or one with no end on the
                body), offsets of the wrong shape or not finite (names the body).
        """
        if self.linear_ties:
            raise ValueError(f"{self.prefix}: tie offsets need finite-rotation ties, not linear")
        if name not in self._index:
            raise ValueError(f"{self.prefix}: no rigid body '{name}' to offset")
        b = self._index[name]
        if self._fe is not None:
            lay = self._problem.layout
            nodes = lay.tied_nodes[b]
            o = None if offsets is None else np.asarray(offsets(lay.X[nodes]), dtype=float)
            if o is not None and (o.shape != (len(nodes), 3) or not np.all(np.isfinite(o))):
                raise ValueError(
                    f"rigid body '{name}': tie offsets must be finite, one 3-vector (m) per "
                    f"tied node ({len(nodes)} here), got shape {o.shape}"
                )
            lay.set_offsets(b, o)
        springs = {k: np.asarray(v, dtype=float) for k, v in (springs or {}).items()}
        on_body = {}
        for j, spring in enumerate(self.springs):
            for i, point in ((2 * j, spring.point_a), (2 * j + 1, spring.point_b)):
                end = self._problem.ends[i]
                if end.kind == "rigid" and end.body == b:
                    on_body[i] = (spring.name, np.asarray(point, dtype=float))
        named = {spring for spring, _ in on_body.values()}
        for spring, o in springs.items():
            if spring not in named or o.shape != (3,) or not np.all(np.isfinite(o)):
                raise ValueError(
                    f"rigid body '{name}': bad spring offset {spring!r}: {o.tolist()} m (the "
                    f"springs on it: {', '.join(sorted(named)) or 'none'}; a finite 3-vector)"
                )
        for i, (spring, point) in on_body.items():
            o = springs.get(spring, np.zeros(3))
            self._problem.ends[i] = self._problem.ends[i]._replace(point=point + o)
        # the residual last assembled is not the state's any more
        self._problem.set_rotation(b, self.bodies[b].rotation)
