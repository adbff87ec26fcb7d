"""The ``jaxstyle play`` page's 3-D scene (viser): the characters drawn as batched meshes (bones as
cylinders, joints as spheres, :func:`bone_transforms`), their predicted future trajectories, the
waypoints, clicks on the ground (:func:`ground_point`) and the camera that follows the first
character. :class:`SceneView` is the part of :class:`jaxstyle.play.server.PlayServer` that draws;
the server serves the page, runs the GUI and the render loop.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

BONE_RADIUS_M = 0.035
JOINT_RADIUS_M = 0.05
COLORS = np.array([[90, 160, 230], [230, 120, 80], [110, 190, 110], [200, 110, 200], [220, 190, 80],
                   [90, 200, 200], [170, 170, 170], [240, 140, 170]], dtype=np.uint8)


def _unit_cylinder(segments: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """A cylinder of radius 1 from z = -0.5 to 0.5 (vertices, faces), capped."""
    a = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.cos(a), np.sin(a)], axis=-1)
    v = np.concatenate([np.c_[ring, np.full(segments, -0.5)], np.c_[ring, np.full(segments, 0.5)],
                        [[0, 0, -0.5], [0, 0, 0.5]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    side = np.concatenate([np.stack([i, j, i + segments], -1), np.stack([j, j + segments, i + segments], -1)])
    caps = np.concatenate([np.stack([np.full(segments, 2 * segments), j, i], -1),
                           np.stack([np.full(segments, 2 * segments + 1), i + segments, j + segments], -1)])
    return v.astype(np.float32), np.concatenate([side, caps]).astype(np.uint32)


def _unit_sphere() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    return np.asarray(mesh.vertices, np.float32), np.asarray(mesh.faces, np.uint32)


def bone_transforms(positions_Jx3: np.ndarray, parents_J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bone (joint with a parent): the midpoint ``(..., B, 3)``, the quaternion ``(..., B, 4)``
    (w x y z) turning +Z onto the bone and the scales ``(..., B, 3)`` (radius, radius, length) of a
    unit cylinder; ``positions`` may carry leading axes (characters)."""
    positions = np.asarray(positions_Jx3)
    child = np.flatnonzero(parents_J >= 0)
    a, b = positions[..., parents_J[child], :], positions[..., child, :]
    d = b - a
    length = np.linalg.norm(d, axis=-1)
    u = d / np.maximum(length, 1e-9)[..., None]
    q = np.stack([1.0 + u[..., 2], -u[..., 1], u[..., 0], np.zeros_like(length)], axis=-1)  # rotation +Z -> u
    flip = q[..., 0] < 1e-6  # u = -Z: half a turn about X
    q[flip] = [0.0, 1.0, 0.0, 0.0]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    scales = np.stack([np.full_like(length, BONE_RADIUS_M), np.full_like(length, BONE_RADIUS_M), length], -1)
    return (a + b) / 2, q, scales


def ground_point(ray_origin, ray_direction) -> tuple[float, float] | None:
    """Where a click's ray meets the floor (y = 0), x z in metres; ``None`` if it points up."""
    o, d = np.asarray(ray_origin, np.float64), np.asarray(ray_direction, np.float64)
    if d[1] > -1e-6:
        return None
    t = -o[1] / d[1]
    return float(o[0] + t * d[0]), float(o[2] + t * d[2])


def _view(client) -> tuple[np.ndarray, np.ndarray] | None:
    """A page's camera ``(position, look_at)``, or None before the page has reported one (viser's
    camera getters assert on a page that has not)."""
    try:
        return np.asarray(client.camera.position), np.asarray(client.camera.look_at)
    except AssertionError:
        return None


class SceneView:
    """The drawing half of the page's server. It uses the server's viser server ``_server``, its
    ``session``, its ``_gui`` (the "Camera follows" checkbox) and ``_guarded`` (callbacks that show
    an error in the page instead of raising), and keeps the scene nodes ``_nodes`` (bones, joints,
    futures), ``_node_count``, ``_target_node`` and the camera offset ``_cam_offset``."""

    def _scene_setup(self) -> None:
        scene = self._server.scene
        scene.set_up_direction("+y")
        scene.configure_default_lights(True, cast_shadow=True)
        scene.add_grid("/ground", width=60.0, height=60.0, plane="xz", cell_size=0.5, section_size=2.0,
                       shadow_opacity=0.3, plane_color=(235, 235, 230), plane_opacity=1.0, infinite_grid=True)
        self._server.initial_camera.look_at = (0.0, 0.9, 0.0)
        self._server.initial_camera.position = tuple(np.array([0.0, 0.9, 0.0]) + self._cam_offset)
        self._cylinder, self._sphere = _unit_cylinder(), _unit_sphere()
        scene.on_click()(self._wrap_click(append=False))
        scene.on_click(modifier="shift")(self._wrap_click(append=True))

    def _wrap_click(self, append: bool):
        def on_click(event) -> None:
            point = ground_point(event.ray_origin, event.ray_direction)
            if point is None:
                return
            self._guarded(lambda: self.session.walk_to(*point, append=append))()

        return on_click

    def _clear_characters(self) -> None:
        for n in self._nodes:
            n.remove()
        self._nodes = []

    def _add_character_nodes(self, frame) -> None:
        """One scene node for the bones of all characters, one for their joints and one for their
        future trajectories (instances coloured per character), so a frame sends three updates
        whatever the number of characters."""
        scene = self._server.scene
        parents = self.session.model.skeleton.parents
        c, j = frame.positions.shape[:2]
        colors = COLORS[np.arange(c) % len(COLORS)].astype(np.uint8)
        mid, q, s = (v.reshape(-1, v.shape[-1]) for v in bone_transforms(frame.positions, parents))
        bones = scene.add_batched_meshes_simple("/characters/bones", *self._cylinder, q, mid, batched_scales=s,
                                                batched_colors=np.repeat(colors, len(mid) // c, axis=0), lod="off",
                                                cast_shadow=True)
        joints = scene.add_batched_meshes_simple(
            "/characters/joints", *self._sphere, np.tile([1.0, 0, 0, 0], (c * j, 1)), frame.positions.reshape(-1, 3),
            batched_scales=np.full(c * j, JOINT_RADIUS_M), batched_colors=np.repeat(colors, j, axis=0), lod="off",
            cast_shadow=True)
        future = scene.add_point_cloud("/characters/future", self._future_points(frame),
                                       colors=np.repeat(colors, frame.future.shape[1], axis=0), point_size=0.08,
                                       point_shape="circle")
        self._nodes = [bones, joints, future]

    @staticmethod
    def _future_points(frame) -> np.ndarray:
        f = frame.future.reshape(-1, 2)
        return np.c_[f[:, 0], np.full(len(f), 0.02), f[:, 1]].astype(np.float32)

    def _update_scene(self, frame, targets) -> None:
        parents = self.session.model.skeleton.parents
        count = len(frame.positions)
        with self._server.atomic():
            if self._nodes and self._node_count != count:  # a character added or removed
                self._clear_characters()
            if not self._nodes:
                self._add_character_nodes(frame)
                self._node_count = count
            else:
                bones, joints, future = self._nodes
                mid, q, s = (v.reshape(-1, v.shape[-1]) for v in bone_transforms(frame.positions, parents))
                bones.batched_positions, bones.batched_wxyzs, bones.batched_scales = mid, q, s
                joints.batched_positions = frame.positions.reshape(-1, 3)
                future.points = self._future_points(frame)
            points = [p for t in targets for p in t]
            if points:
                xyz = np.array([[x, 0.03, z] for x, z in points], np.float32)
                if self._target_node is None:
                    self._target_node = self._server.scene.add_point_cloud(
                        "/targets", xyz, colors=(220, 40, 40), point_size=0.2, point_shape="circle")
                else:
                    self._target_node.points = xyz
                self._target_node.visible = True
            elif self._target_node is not None:
                self._target_node.visible = False
            self._follow(frame)

    def _follow(self, frame) -> None:
        """Move every page's camera with the first character at a fixed offset (the view's angle
        when "Camera follows" was last switched on; the page's own camera controls work while it
        is off)."""
        if not self._gui["follow"].value:
            return
        at = np.array([frame.origin[0, 0], 0.9, frame.origin[0, 1]])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a page closing meanwhile
            for client in self._server.get_clients().values():
                # per page, so a page that connects later (or whose own report lagged) is put right too
                view = _view(client)
                if view is None or np.linalg.norm(view[1] - at) < 0.01:
                    continue
                with client.atomic():
                    # position first: viser's position setter moves look_at by the same offset
                    # (keeping the view's direction), so setting look_at last is what leaves the
                    # page looking at the character
                    client.camera.position = at + self._cam_offset
                    client.camera.look_at = at

    def _on_follow(self) -> None:
        """Keep the current view's angle and distance when following is switched on."""
        if not self._gui["follow"].value:
            return
        for client in self._server.get_clients().values():
            view = _view(client)
            if view is None:
                continue
            offset = view[0] - view[1]
            if np.isfinite(offset).all() and 0.5 < np.linalg.norm(offset) < 50:
                self._cam_offset = offset
            break

    def camera_yaw(self) -> float:
        """The yaw of the first page's view direction (0: looking along +Z)."""
        for client in self._server.get_clients().values():
            view = _view(client)
            if view is None:
                continue
            d = view[1] - view[0]
            if np.hypot(d[0], d[2]) > 1e-6:
                return float(math.atan2(d[0], d[2]))
        return 0.0
