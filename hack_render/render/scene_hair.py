"""Hair in a built :class:`~hack_render.render.scene.HeadScene`: its groom posed on the
mesh (remembered for the last vertices) and another groom swapped into the scene's hair
slots in place (``render/hair_shapes.py``'s slots). :class:`SceneHair` holds these
methods; ``scene.py`` builds the scene."""

from __future__ import annotations

import numpy as np

from hack_render.errors import HackError
from hack_render.hair.pose import pose_groom
from hack_render.render.hair_shapes import hair_shapes, slots_take, write_slots
from hack_render.render.scene_images import as_points


class SceneHair:
    """The groom of a built scene (:class:`~hack_render.render.scene.HeadScene` extends
    it: its ``hair``, ``hair_shapes``, ``hair_slots``, ``params`` and ``_vertices`` are
    what these read and write)."""

    def pose_hair(self, vertices) -> dict[str, np.ndarray] | None:
        """The groom's strands on ``vertices`` (N, 3): {group: (S, K, 3)} control points
        (:func:`hack_render.hair.pose.pose_groom`, with collisions), None when bald. Pure
        NumPy on the groom alone: a caller may pose the next frame on another thread and
        hand the result to :meth:`set_vertices` (``hair_posed``)."""
        if self.hair is None:
            return None
        return pose_groom(self.hair, as_points(vertices).reshape(-1, 3))

    def _pose_hair(self, v: np.ndarray, posed=None) -> dict[str, np.ndarray]:
        """:meth:`pose_hair` of ``v`` (or ``posed``, already computed for ``v``); posing
        with collisions costs 0.5-5 s for a full head of hair, so the last one is
        remembered."""
        if self._hair_posed_for is not None and np.array_equal(self._hair_posed_for[0], v):
            return self._hair_posed_for[1]
        posed = posed if posed is not None else pose_groom(self.hair, v)
        self._hair_posed_for = (v.copy(), posed)
        return posed

    def takes_hair(self, groom) -> bool:
        """Whether :meth:`set_hair` takes ``groom`` into this scene: it has hair slots, the
        groom has lashes (a slotted scene has no lash cards) and fits the slots."""
        return bool(self.hair_slots) and slots_take(groom, self.hair_slots)

    def set_hair(self, groom, *, vertices=None, hair_posed=None, update: bool = True) -> None:
        """Render ``groom`` instead of the present one, in place: a scene built with
        ``hair_slots`` (:meth:`takes_hair`) renders what a new ``HeadScene(...,
        hair=groom, hair_slots=<the same slots>)`` would, without loading a scene or compiling its
        kernels again. The strands are posed on ``vertices`` (default: the mesh's
        present vertices; given: the ones a :meth:`set_vertices` that follows moves the
        mesh to, without posing them again) or given posed (``hair_posed``,
        :meth:`pose_hair` of those vertices with this groom). ``update=False`` defers
        ``params.update()``."""
        if not self.takes_hair(groom):
            raise HackError("set_hair: " + (
                "this scene has no hair slots; build it with HeadScene(..., hair_slots=True)"
                if not self.hair_slots else "expected a groom with lashes (a scene with hair "
                "slots renders the lashes as strands) that fits the slots "
                "(hair_shapes.needed_segments); build a HeadScene with this groom"))
        v = self._vertices if vertices is None else as_points(vertices).reshape(-1, 3)
        self.hair, self.hair_shapes = groom, hair_shapes(groom)
        self._hair_posed_for = None
        posed = self._pose_hair(v, hair_posed)
        write_slots(self.params, groom, posed, self.hair_shapes, self.hair_slots, v.mean(0),
                    structure=True)
        self._hair_written = posed
        if update:
            self.params.update()
