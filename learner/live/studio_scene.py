"""The studio's 3-D view: the session's MuJoCo geoms in a viser scene, through mjviser.

mjviser's `ViserMujocoScene` turns every geom of one `MjModel` into (batched) viser meshes once,
then moves them from `MjData` each frame. It bakes geom sizes at construction, and a morph (or a
shape controller's reset) hands out a new compiled model, so when `session.env.model` changes
identity the scene's two root nodes are removed and a new `ViserMujocoScene` is built for the new
model (about 0.1 s for the lower biped).
"""

from __future__ import annotations

import numpy as np
import viser
from mjviser import ViserMujocoScene

BODIES = "/bodies"
"""mjviser's root for moving geoms; we own a frame there so one `remove()` drops them all."""
CAMERA_AZIMUTH_DEG, CAMERA_ELEVATION_DEG = 120.0, 15.0


class CharacterScene:
    """The character (and the floor, projectiles...) of whatever model the session has now."""

    def __init__(self, server: viser.ViserServer):
        self.server = server
        self.scene: ViserMujocoScene | None = None
        self.model = None
        self.rebuilds = 0
        self.follow = True
        """Camera follow: the world is shifted so the root body stays at the origin (mjviser's
        tracking), so a viewer orbits around the moving character."""
        self._visible = True
        self._root: viser.FrameHandle | None = None
        self._distance = 3.0
        self._elevation = CAMERA_ELEVATION_DEG
        self._target = np.zeros(3)
        server.on_client_connect(self._aim_camera)

    @property
    def visible(self) -> bool:
        return self._visible

    @visible.setter
    def visible(self, value: bool) -> None:
        """Show or hide the moving bodies (the floor stays); tests compare the two."""
        self._visible = bool(value)
        if self._root is not None:
            self._root.visible = self._visible

    def update(self, session) -> None:
        """Push the session's pose; rebuild first when its model was recompiled."""
        model = session.env.model
        if model is not self.model:
            self._rebuild(session)
        assert self.scene is not None
        self.scene.camera_tracking_enabled = self.follow
        self.scene.update_from_mjdata(session.env.data)

    def _rebuild(self, session) -> None:
        model = session.env.model
        # NOTE: another character (another checkpoint), not a morph of this one: aim the viewers anew
        new_character = self.model is None or (model.nbody, model.ngeom) != (self.model.nbody, self.model.ngeom)
        with self.server.atomic():
            if self.scene is not None:
                self._root.remove()
                self.scene.fixed_bodies_frame.remove()
            self._root = self.server.scene.add_frame(BODIES, show_axes=False, visible=self._visible)
            self.scene = ViserMujocoScene(self.server, model, num_envs=1)
            self.scene._tracked_body_id = int(session.root_body)  # NOTE: mjviser tracks the first free body by default
        self.model = model
        self.rebuilds += 1
        if new_character:  # NOTE: a task may say where to stand (the 24 cm reach arm); else by the body's height
            view = session.view
            self._distance = view.get("distance_m") or float(np.clip(2.5 * session.body_height_m(), 2.0, 8.0))
            self._elevation = view.get("elevation_deg") or CAMERA_ELEVATION_DEG
            self.set_follow(self.follow, session.env.data.xpos[session.root_body])

    def camera_offset(self) -> np.ndarray:
        az, el = np.deg2rad(CAMERA_AZIMUTH_DEG), np.deg2rad(self._elevation)
        return self._distance * np.array([-np.cos(el) * np.cos(az), -np.cos(el) * np.sin(az), np.sin(el)])

    def _aim_camera(self, client: viser.ClientHandle) -> None:
        client.camera.position = self._target + self.camera_offset()  # NOTE: first: viser moves look_at along with it
        client.camera.look_at = self._target

    def set_follow(self, follow: bool, root_xyz: np.ndarray | None = None) -> None:
        """Toggle camera follow; every viewer is re-aimed at the character (at the origin when
        following, else at `root_xyz`, where the character is in the world)."""
        self.follow = bool(follow)
        self._target = np.zeros(3) if self.follow or root_xyz is None else np.asarray(root_xyz, float).copy()
        for client in self.server.get_clients().values():
            self._aim_camera(client)
