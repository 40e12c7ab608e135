"""The fit's typed state: what the stages read and update.

- :class:`Level`: one view's photometric level (virtual camera, warped photo, masks,
  renderer), built by :func:`hack_render.fit.photometric.setup_level`.
- :class:`View`: one photo, its detection and its own parameters (camera, head and neck
  pose, expression when per view, lighting), the landmark and silhouette terms'
  correspondences of the current iterate, and its current :class:`Level`.
- :class:`FitState`: the model, the appearance model, the shared parameters (beta, psi,
  alpha, eta, tau, the per-texel albedo delta), the views, and the fixed pieces the loss
  terms use (jaw contour, landmark embedding and weights, model silhouette); the model's
  forward pass, the projection and the skin maps of the current parameters.

Nothing here optimises: stages (``geometric.py``, ``photometric.py``) take a state and a
config and return reports; loss terms live in ``terms.py``.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from hack_render.errors import HackError
from hack_render.fit import gaze
from hack_render.fit import teeth as teeth_rig
from hack_render.fit.camera import R0
from hack_render.fit.landmarks import JawContour
from hack_render.fit.lighting import Lighting
from hack_render.fit.photo import Photo
from hack_render.geometry.larynx import ETA_RANGE, TAU_RANGE_M
from hack_render.geometry.skeleton import distribute_head_rotation
from hack_render.geometry.subset import VertexSubset
from hack_render.vision.detection import Detection


@dataclass
class Level:
    """One view's photometric level at ``res`` px: the virtual camera, the homography
    ``H`` (virtual pixels -> photo pixels), the photo resampled into it (linear RGB), the
    landmark face polygon (``photo_mask``), the landmarks in virtual pixels, the atlas
    height of its skin maps (None: the model's own), the renderer, and the skin mask of
    the photo term (the polygon and the rendered face, eroded; :func:`update_mask`)."""

    res: int
    camera: object
    H: np.ndarray
    target: torch.Tensor
    photo_mask: np.ndarray
    points_v: np.ndarray
    map_height: int | None
    renderer: object
    mask: torch.Tensor | None = None
    erode: int = 1
    uv: np.ndarray | None = None  # (res, res, 2) the model's UV per pixel (update_mask)
    # (h, 2h) how much light from each of the lighting's directions reaches the photo
    # term's skin: the mean clamped cosine over its normals (update_mask)
    reach: torch.Tensor | None = None


@dataclass
class View:
    """One photo and its own parameters (torch leaves)."""

    photo: Photo
    detection: Detection
    log_focal: torch.Tensor
    transl: torch.Tensor          # camera t (3,), metres: x_cam = R0 X + t
    head_angles: torch.Tensor     # (3,) whole-head Euler angles, radians
    dtheta: torch.Tensor          # (8, 3) residual per-joint axis-angle
    global_orient: torch.Tensor   # (3,) torso rotation
    psi: torch.Tensor | None      # (1, E) when expressions are per view
    lighting: Lighting | None = None
    lighting_init: list = field(default_factory=list)  # init_lobes' report ("sg" lighting)
    silhouette: object = None     # PhotoSilhouette (person mask), or None: no silhouette term
    silhouette_note: str = ""     # where the mask came from, or why there is none
    # (h, w) bool at the photo's size: occluders over the face (hair, hands; the vision
    # package's segmentation), left out of the photometric term; None: none known
    occluder: np.ndarray | None = None
    shoulders: bool = False       # the person mask shows the shoulders (torso orientation)
    # (h, w) bool: the segmentation's skin inside the face oval (no hair, clothes,
    # occluders); the bake takes its pixels only; None: no segmentation
    skin: np.ndarray | None = None
    # (h, w) bool: the segmentation's hair (its shadow on the skin beside it leaves the
    # bake: bake_weights.pixel_weights); None: no segmentation
    hair: np.ndarray | None = None
    # (h, w) bool: the segmentation's clothes (kept in front of the render in
    # render_over_photo.png: outputs.photo_layer); None: no segmentation
    clothes: np.ndarray | None = None
    # (h, w) bool: the face mesh's oval inside the person (the segmentation's face);
    # None: no segmentation
    face: np.ndarray | None = None
    embedded: bool = False        # landmarks are the embedding's points (else vertices)
    # the jawline's contour vertices (17,) matched at the last re-match, None before
    jaw: np.ndarray | None = None
    # the silhouette term's outer-contour points (edge pairs, parameters), None before
    sil_contour: tuple | None = None
    level: Level | None = None    # the current photometric level
    # (2,) the eyeballs' gaze (yaw, pitch), radians (``fit/gaze.py``; the eyes' stage,
    # ``fit/eyes.py``); None: looking ahead
    gaze: torch.Tensor | None = None
    # (h, w) bool at the photo's size: the person's eye openings (the face mesh's lid
    # contours, face_mesh.opening_masks; set by the final stage); None: not known
    eye_opening: np.ndarray | None = None
    # (h, w) bool at the photo's size: the person's mouth opening (the face mesh's inner
    # lip contour, face_mesh.opening_masks; set by the final stage for the parts' bake);
    # None: not known
    mouth_opening: np.ndarray | None = None
    # the face mesh's 478 points on the photo (face_mesh.view_mesh's cache: the mouth's
    # and the final stages read them), with the detected points they were found near
    mesh478: tuple | None = None

    @property
    def focal(self) -> torch.Tensor:
        return torch.exp(self.log_focal)

    @property
    def renderer(self):
        """The current level's renderer (None before the photometric stage)."""
        return self.level.renderer if self.level is not None else None


@dataclass
class FitState:
    """The model, the shared parameters (torch leaves), the views and the fixed pieces the
    loss terms use. Build with :func:`hack_render.fit.fitter.init_state`."""

    model: object
    appearance: object            # AppearanceModel, or None: a constant albedo
    beta: torch.Tensor            # (1, B)
    psi: torch.Tensor             # (1, E) shared expression
    eta: torch.Tensor             # (1,) larynx
    tau: torch.Tensor             # (1,) swallow
    alpha: torch.Tensor           # (1, A) appearance coefficients
    const_albedo: torch.Tensor    # (3,) without an appearance model
    jaw: JawContour
    lmk_idx: torch.Tensor         # (68,) the model's landmark vertices
    embedding: object             # LandmarkEmbedding, or None: the vertices
    lmk_w: torch.Tensor           # (68,) configured landmark weights
    silhouette: object = None     # ModelSilhouette, or None: no silhouette term
    views: list = field(default_factory=list)
    albedo_delta: torch.Tensor | None = None   # (H, 2H, 3) per-texel refinement
    coarse_appearance: dict = field(default_factory=dict)  # (height, n_alpha) -> model
    albedo_balance: dict = field(default_factory=dict)  # photometric.balance_albedo's report
    # (beta, PersonalizedHack) of :meth:`forward_views` while beta takes no gradient
    personal: tuple | None = field(default=None, repr=False)
    # (the vertices :meth:`landmark_reads` lists, their VertexSubset or None)
    reads: tuple | None = field(default=None, repr=False)
    # (1,) the upper teeth's drop under the upper lip, metres (``fit/teeth.py``; the
    # mouth's stage, ``fit/mouth.py``); None: where the model places them
    teeth: torch.Tensor | None = None

    @property
    def faces(self) -> torch.Tensor:
        return self.model.faces

    def view_psi(self, v: View) -> torch.Tensor:
        return v.psi if v.psi is not None else self.psi

    def psi_changed(self, v: View, ids: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """The view's expression (detached) with ``delta`` added to its weights ``ids``,
        clamped to [0, 1]: the eyes' and the mouth's stages fit such a change of a few
        shapes (differentiable in ``delta``)."""
        p = self.view_psi(v).detach()
        return p.index_put((torch.zeros_like(ids), ids), (p[0, ids] + delta).clamp(0.0, 1.0))

    def leaves(self) -> list[torch.Tensor]:
        """Every parameter the stages optimise (shared and per view; the per-texel
        albedo delta, the teeth's drop and the views' gazes where they exist)."""
        out = [self.beta, self.psi, self.eta, self.tau, self.alpha, self.const_albedo,
               self.albedo_delta, self.teeth]
        for v in self.views:
            out += [v.log_focal, v.transl, v.head_angles, v.dtheta, v.global_orient, v.psi,
                    v.gaze]
        return [t for t in out if isinstance(t, torch.Tensor)]

    @contextlib.contextmanager
    def grads_only(self, params: list[torch.Tensor]):
        """Within the block, only ``params`` among :meth:`leaves` require a gradient: a
        stage's backward pass then skips the others' (the camera stage's through the
        identity and expression bases was half its time). The same step for ``params``;
        their flags restored after."""
        keep = {id(p) for p in params}
        off = [t for t in self.leaves() if t.requires_grad and id(t) not in keep]
        for t in off:
            t.requires_grad_(False)
        try:
            yield
        finally:
            for t in off:
                t.requires_grad_(True)

    def theta(self, v: View) -> torch.Tensor:
        """(1, 8, 3) neck pose: the head rotation's anatomical share plus the residual."""
        return (distribute_head_rotation(v.head_angles, clamp=False) + v.dtheta)[None]

    def thetas(self) -> torch.Tensor:
        """(V, 8, 3) every view's :meth:`theta`, in one call of the anatomical share."""
        h = torch.stack([v.head_angles for v in self.views])
        return distribute_head_rotation(h, clamp=False) + torch.stack(
            [v.dtheta for v in self.views])

    def forward(self, v: View, psi: torch.Tensor | None = None):
        """The model's output for view ``v`` (``psi``: this expression instead of the
        view's), its eyeballs turned by the view's gaze (``fit/gaze.py``) where it has one
        and its upper teeth lowered by :attr:`teeth` (``fit/teeth.py``) where it is set."""
        out = self.model(beta=self.beta, psi=self.view_psi(v) if psi is None else psi,
                         theta=self.theta(v), global_orient=v.global_orient[None],
                         eta=self.eta, tau=self.tau)
        if v.gaze is None and self.teeth is None:
            return out
        verts = out.vertices[0]
        if v.gaze is not None:
            verts = gaze.apply_gaze(gaze.eye_rig(self.model), verts, out.rest_vertices[0],
                                    v.gaze)
        if self.teeth is not None:
            verts = teeth_rig.apply_teeth(teeth_rig.teeth_rig(self.model), verts,
                                          out.rest_vertices[0], self.teeth)
        return dataclasses.replace(out, vertices=verts[None])

    def landmark_reads(self):
        """The vertices the landmark terms read (``terms.model_landmarks``), and their
        :class:`~hack_render.geometry.subset.VertexSubset` (None where the model does not
        move them all rigidly with the skull): the embedding's triangles, the landmark
        vertices, the jawline's candidates and every vertex of the faces about those
        (the re-match's normals there). Made once per state."""
        if self.reads is None:
            cand = np.concatenate([np.asarray(c).reshape(-1) for c in self.jaw.candidates])
            F = self.faces.numpy()
            ring = F[np.isin(F, cand).any(1)].reshape(-1)
            ids = [self.lmk_idx.numpy(), cand, ring]
            if self.embedding is not None:
                ids.append(np.asarray(self.embedding.vertex_ids).reshape(-1))
            index = np.unique(np.concatenate(ids).astype(np.int64))
            self.reads = (index, VertexSubset.build(self.model, index))
        return self.reads

    def forward_views(self, landmarks_only: bool = False,
                      thetas: torch.Tensor | None = None) -> list[torch.Tensor]:
        """Every view's posed vertices (N, 3), as :meth:`forward`'s: one batched forward
        of the model where there are several views, none has a gaze and the teeth are the
        model's (the batch shares the identity; forward and backward in about half the time of one forward per
        view), else one per view.

        ``landmarks_only``: the caller reads only :meth:`landmark_reads`' vertices (the
        camera stage, and the shape stage without a silhouette term); where the model
        moves them rigidly with the skull, only they are computed
        (``geometry/subset.py``: the same values to rounding, a twentieth of the work) and
        every other vertex is left at zero. ``thetas``: :meth:`thetas`, when the caller
        has them."""
        views = self.views
        if self.teeth is not None or any(v.gaze is not None for v in views):
            return [self.forward(v).vertices[0] for v in views]
        sub = self.landmark_reads()[1] if landmarks_only else None
        if sub is None and len(views) < 2:
            return [self.forward(v).vertices[0] for v in views]
        B = len(views)
        kw = {"psi": torch.cat([self.view_psi(v) for v in views]),
              "theta": self.thetas() if thetas is None else thetas,
              "global_orient": torch.stack([v.global_orient for v in views])}
        if sub is not None:
            pts = sub(self.beta, **kw)
            full = pts.new_zeros(B, self.model.num_vertices, 3)
            return list(full.index_copy(1, sub.index, pts).unbind(0))
        kw |= {"eta": self.eta.expand(B), "tau": self.tau.expand(B)}
        if self.beta.requires_grad:
            return list(self.model(beta=self.beta, **kw).vertices.unbind(0))
        # the identity fixed (the camera stage): its bases made once
        # (:meth:`~hack_render.geometry.model.HackModel.personalize`) and kept while beta is
        if self.personal is None or not torch.equal(self.personal[0], self.beta):
            self.personal = (self.beta.detach().clone(), self.model.personalize(self.beta))
        return list(self.personal[1](**kw).vertices.unbind(0))

    def project(self, v: View, X: torch.Tensor) -> torch.Tensor:
        """World points (..., 3) -> photo pixels (..., 2) (continuous coordinates)."""
        cam = X @ R0.T + v.transl
        uv = v.focal * cam[..., :2] / cam[..., 2:3].clamp_min(1e-4)
        return uv + torch.tensor([v.photo.width / 2.0, v.photo.height / 2.0])

    def camera_centre(self, v: View) -> np.ndarray:
        return (-R0.T @ v.transl.detach()).numpy()

    def clamp_(self) -> None:
        """Project the bounded parameters back into range after a step: psi to [0, 1],
        eta and tau to their anatomical ranges (larynx.py; E_larynx penalises the excess
        before this)."""
        with torch.no_grad():
            self.psi.clamp_(0.0, 1.0)
            for v in self.views:
                if v.psi is not None:
                    v.psi.clamp_(0.0, 1.0)
            self.eta.clamp_(*ETA_RANGE)
            self.tau.clamp_(*TAU_RANGE_M)

    def maps(self, with_delta: bool = True, height: int | None = None,
             alpha: torch.Tensor | None = None) -> dict:
        """Current skin maps: torch (H, 2H, C) diffuse, specular, roughness, normal
        (``with_delta``: the per-texel albedo refinement added, when there is one).
        ``height``: a coarser atlas (the appearance model's height / 2^k, see
        :meth:`~appearance.model.AppearanceModel.downsampled`) for coarse photometric
        levels; None: the model's own. ``alpha``: the maps of these coefficients (1, A)
        instead of the state's."""
        if self.appearance is None:
            h = 16
            d = self.const_albedo.clamp(0, 1).expand(h, 2 * h, 3)
            return {"albedo": d, "specular": torch.full((h, 2 * h, 1), 0.6),
                    "roughness": torch.full((h, 2 * h, 1), 0.5), "normal": None}
        app = self.appearance
        if height is not None and height != app.height:
            if with_delta and self.albedo_delta is not None:
                raise HackError("maps: the per-texel albedo refinement is at the full atlas "
                                f"({app.height} px), not at {height} px.")
            key = (int(height), self.alpha.shape[1])
            if key not in self.coarse_appearance:
                self.coarse_appearance[key] = app.downsampled(*key)
            app = self.coarse_appearance[key]
        m = app.maps(self.alpha if alpha is None else alpha)
        d = m.diffuse[0]
        if with_delta and self.albedo_delta is not None:
            d = (d + self.albedo_delta).clamp(0.0, 1.0)
        return {"albedo": d, "specular": m.specular[0], "roughness": m.roughness[0],
                "normal": m.normal[0]}

