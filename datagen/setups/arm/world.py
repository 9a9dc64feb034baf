"""The arm in a room (docs/MODEL.md §2.3, §2.4) on SAPIEN 3: a planar arm whose end carries a 16×16 camera.

The arm is a SAPIEN articulation (revolute joints about the vertical; for arm6 two prismatic
joints set the 2nd and 3rd segment lengths); p is read from its end link. The camera sits at the
arm's end, p + shift in room coordinates, with a fixed world orientation. The arm's visuals sit
above the camera's horizontal plane, so the camera (whose view is entirely below it) never sees them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smspace.datagen.setups.arm.room import ROOM_HALF, WALL_HEIGHT, Room, draw_room
from smspace.datagen.setups.arm.vulkan import require_render_device
from smspace.datagen.walks import continuous_walk

BASE_HEIGHT = 1.6
IMAGE_SIZE = 16
FOVY = math.pi / 4
NEAR, FAR = 0.05, 20.0
PITCH = math.atan2(1.8, 2.5)  # 0.624 rad down
SHIFT_BOUND = 1.75
AMBIENT = 0.5
SUN = 0.5
SHADERS = Path(__file__).resolve().parent / "shaders" / "lambert"
CAMERAS = 16  # frames submitted per update_render: ~5-10 % more renders/s on lavapipe than one at a time


@dataclass(frozen=True)
class ArmBody:
    n_motor: int
    segment: float
    regular_levels: int  # regular sampling: linspace(-1, 1, levels) ** n_motor


ARM3 = ArmBody(n_motor=3, segment=0.5, regular_levels=6)
ARM6 = ArmBody(n_motor=6, segment=0.375, regular_levels=5)


def planar_fk(m: np.ndarray) -> np.ndarray:
    """Σ l_i (cos θ_i, sin θ_i), θ = cumsum(π·m_revolute); arm6 lengths are 0.375·[1, m5, m6, 1]."""
    m = np.asarray(m, np.float64)
    if m.shape[1] == 3:
        angles, lengths = np.cumsum(np.pi * m, axis=1), np.full((len(m), 3), ARM3.segment)
    else:
        angles = np.cumsum(np.pi * m[:, :4], axis=1)
        one = np.ones(len(m))
        lengths = ARM6.segment * np.stack([one, m[:, 4], m[:, 5], one], axis=1)
    return np.stack([(lengths * np.cos(angles)).sum(1), (lengths * np.sin(angles)).sum(1)], axis=1)


def _quat(axis: tuple[float, float, float], angle: float) -> list[float]:
    s = math.sin(angle / 2)
    return [math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s]  # SAPIEN: w, x, y, z


Z_JOINT = _quat((0.0, 1.0, 0.0), -math.pi / 2)  # a joint's axis is its frame's x: turn x onto z
CAMERA_Q = _quat((0.0, 1.0, 0.0), PITCH)  # camera looks along +x; +pitch about y tilts it down


class ArmWorld:
    """One room and one arm; the SAPIEN scene is built on first use, in the process that uses it."""

    static_shift = np.zeros(2)
    sensor_shape = (IMAGE_SIZE, IMAGE_SIZE, 3)
    sensor_dtype = np.dtype(np.uint8)

    def __init__(self, world_seed: int, n_motor: int = 3, arm_visuals: bool = True):
        if n_motor not in (3, 6):
            raise ValueError(f"arms have 3 or 6 motors, not {n_motor}")
        self.body = ARM3 if n_motor == 3 else ARM6
        self.n_motor = n_motor
        self.room: Room = draw_room(np.random.default_rng(np.random.SeedSequence(world_seed, spawn_key=(0,))))
        self.arm_visuals = arm_visuals
        self._scene = None
        self._room_moved = False

    # -- the SAPIEN scene ---------------------------------------------------------------------
    def _build(self) -> None:
        require_render_device()
        import sapien

        sapien.render.set_camera_shader_dir(str(SHADERS))
        scene = sapien.Scene()
        scene.set_ambient_light([AMBIENT] * 3)
        scene.add_directional_light(list(-np.ones(3) / math.sqrt(3)), [SUN] * 3, shadow=False)
        self._room_actors = self._build_room(sapien, scene)
        self._articulation, self._end = self._build_arm(sapien, scene)
        self._cameras = [
            scene.add_camera(f"sensor{k}", IMAGE_SIZE, IMAGE_SIZE, FOVY, NEAR, FAR) for k in range(CAMERAS)
        ]
        self._scene = scene

    def _textured(self, sapien, rgba: np.ndarray):
        material = sapien.render.RenderMaterial(base_color=[1.0, 1.0, 1.0, 1.0])
        material.set_base_color_texture(sapien.render.RenderTexture2D(rgba, "R8G8B8A8Unorm", filter_mode="linear"))
        return material

    def _build_room(self, sapien, scene) -> list[tuple[object, list[float], list[float]]]:
        """Floor, four walls and 16 objects; returns (actor, position, quaternion) for moving the room."""
        placed = []

        def add(builder, name: str, pos: list[float], q: list[float]) -> None:
            actor = builder.build_kinematic(name=name)
            actor.set_pose(sapien.Pose(pos, q))
            placed.append((actor, pos, q))

        floor = scene.create_actor_builder()
        floor.add_box_visual(
            half_size=[ROOM_HALF, ROOM_HALF, 0.05], material=self._textured(sapien, self.room.floor_texture)
        )
        add(floor, "floor", [0.0, 0.0, -0.05], [1.0, 0.0, 0.0, 0.0])
        wall_material = self._textured(sapien, self.room.wall_texture)
        for i, (x, y) in enumerate(
            ((ROOM_HALF + 0.05, 0.0), (-ROOM_HALF - 0.05, 0.0), (0.0, ROOM_HALF + 0.05), (0.0, -ROOM_HALF - 0.05))
        ):
            wall = scene.create_actor_builder()
            wall.add_box_visual(half_size=[0.05, ROOM_HALF + 0.1, WALL_HEIGHT / 2], material=wall_material)
            q = [1.0, 0.0, 0.0, 0.0] if i < 2 else _quat((0.0, 0.0, 1.0), math.pi / 2)
            add(wall, f"wall{i}", [x, y, WALL_HEIGHT / 2], q)
        upright = sapien.Pose(q=_quat((0.0, 1.0, 0.0), math.pi / 2))  # capsules and cylinders lie along x
        for i, obj in enumerate(self.room.objects):
            b = scene.create_actor_builder()
            mat = sapien.render.RenderMaterial(base_color=[*obj.rgb, 1.0])
            if obj.shape == "box":
                b.add_box_visual(half_size=[0.375] * 3, material=mat)
            elif obj.shape == "sphere":
                b.add_sphere_visual(radius=0.375, material=mat)
            elif obj.shape == "cylinder":
                b.add_cylinder_visual(pose=upright, radius=0.375, half_length=0.375, material=mat)
            else:
                b.add_capsule_visual(pose=upright, radius=0.25, half_length=0.125, material=mat)
            add(b, f"object{i}", [obj.x, obj.y, 0.375], _quat((0.0, 0.0, 1.0), obj.yaw))
        return placed

    def _build_arm(self, sapien, scene):
        """Fixed base at height 1.6; qpos order = joint order below (see _qpos)."""
        builder = scene.create_articulation_builder()
        builder.set_initial_pose(sapien.Pose([0.0, 0.0, BASE_HEIGHT]))
        grey = sapien.render.RenderMaterial(base_color=[0.3, 0.3, 0.3, 1.0])
        root = builder.create_link_builder()
        root.set_name("base")
        seg = self.body.segment
        # (joint type, offset along the parent link) for each moving link
        chain = (
            [("revolute", 0.0)] + [("revolute", seg)] * 2
            if self.n_motor == 3
            else [
                ("revolute", 0.0),
                ("revolute", seg),
                ("prismatic", 0.0),
                ("revolute", 0.0),
                ("prismatic", 0.0),
                ("revolute", 0.0),
            ]
        )
        parent = root
        for i, (kind, offset) in enumerate(chain):
            link = builder.create_link_builder(parent)
            link.set_name(f"link{i}")
            if kind == "revolute":
                link.set_joint_properties(
                    "revolute",
                    [[-math.pi, math.pi]],
                    sapien.Pose([offset, 0, 0], Z_JOINT),
                    sapien.Pose([0, 0, 0], Z_JOINT),
                )
            else:
                link.set_joint_properties("prismatic", [[-seg, seg]], sapien.Pose([offset, 0, 0]), sapien.Pose())
            if self.arm_visuals:  # all above the camera's horizontal plane
                link.add_sphere_visual(pose=sapien.Pose([0, 0, 0.04]), radius=0.03, material=grey)
                if kind == "revolute" and (self.n_motor == 3 or i in (0, 5)):
                    link.add_box_visual(
                        pose=sapien.Pose([seg / 2, 0, 0.04]), half_size=[seg / 2, 0.012, 0.012], material=grey
                    )
            parent = link
        end = builder.create_link_builder(parent)
        end.set_name("sensor_mount")
        end.set_joint_properties("fixed", [], sapien.Pose([seg, 0, 0]), sapien.Pose())
        articulation = builder.build(fix_root_link=True)
        return articulation, articulation.links[-1]

    # -- kinematics ---------------------------------------------------------------------------------
    def _qpos(self, m: np.ndarray) -> np.ndarray:
        if self.n_motor == 3:
            return np.pi * m
        seg = self.body.segment
        return np.stack(
            [np.pi * m[:, 0], np.pi * m[:, 1], seg * m[:, 4], np.pi * m[:, 2], seg * m[:, 5], np.pi * m[:, 3]], axis=1
        )

    def positions(self, m: np.ndarray) -> np.ndarray:
        """The end link's horizontal position relative to the base, read from SAPIEN."""
        if self._scene is None:
            self._build()
        q = self._qpos(np.asarray(m, np.float64)).astype(np.float32)
        out = np.empty((len(q), 2))
        for i, qi in enumerate(q):
            self._articulation.set_qpos(qi)
            out[i] = self._end.entity_pose.p[:2]
        return out

    def sample_motors(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        m = rng.uniform(-1.0, 1.0, (n, self.n_motor))
        return m, self.positions(m)

    def walk_motors(
        self, rng: np.random.Generator, episodes: int, length: int, step: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Walks in the continuous motor space (datagen/walks.py), with the positions they reach."""
        m = continuous_walk(rng, self.n_motor, episodes, length, step)
        p = self.positions(m.reshape(-1, self.n_motor))
        return m, p.reshape(episodes, length + 1, 2)

    def sample_shifts(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(-SHIFT_BOUND, SHIFT_BOUND, (n, 2))

    def regular_sampling(self) -> tuple[np.ndarray, np.ndarray]:
        levels = np.linspace(-1.0, 1.0, self.body.regular_levels)
        m = np.stack(np.meshgrid(*[levels] * self.n_motor, indexing="ij"), axis=-1).reshape(-1, self.n_motor)
        return m, self.positions(m)

    # -- rendering ----------------------------------------------------------------------------------
    def render(self, camera_xy: np.ndarray, room_offset: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Images (n, 16, 16, 3) uint8 seen from camera positions (room coordinates, height 1.6),
        with the whole room translated by room_offset (only tests move the room)."""
        if self._scene is None:
            self._build()
        import sapien

        self._place_room(sapien, room_offset)
        xy = np.asarray(camera_xy, np.float64)
        out = np.empty((len(xy), IMAGE_SIZE, IMAGE_SIZE, 3), np.uint8)
        for start in range(0, len(xy), CAMERAS):
            chunk = xy[start : start + CAMERAS]
            cameras = self._cameras[: len(chunk)]
            for camera, (x, y) in zip(cameras, chunk, strict=True):
                camera.entity.set_pose(sapien.Pose([float(x), float(y), BASE_HEIGHT], CAMERA_Q))
            self._scene.update_render()  # without it the previous poses would be drawn
            for camera in cameras:
                camera.take_picture()
            for k, camera in enumerate(cameras):
                out[start + k] = np.clip(np.rint(camera.get_picture("Color")[..., :3] * 255.0), 0, 255)
        if room_offset != (0.0, 0.0):
            self._place_room(sapien, (0.0, 0.0))
        return out

    def _place_room(self, sapien, offset: tuple[float, float]) -> None:
        if offset == (0.0, 0.0) and not self._room_moved:
            return
        for actor, pos, q in self._room_actors:
            actor.set_pose(sapien.Pose([pos[0] + offset[0], pos[1] + offset[1], pos[2]], q))
        self._room_moved = offset != (0.0, 0.0)

    def sense(self, p: np.ndarray, shift: np.ndarray) -> np.ndarray:
        return self.render(np.asarray(p) + np.asarray(shift))


def overhead_view(world: ArmWorld, size: int = 512, height: float = 9.0) -> np.ndarray:
    """The room seen from straight above (uint8, size × size × 3, +x up, +y left), the arm at its
    last posed state; `overhead_pixel` maps floor points to pixels. For previews only: it adds a
    camera to the world's scene."""
    if world._scene is None:
        world._build()
    import sapien

    half = ROOM_HALF + 0.1
    fovy = 2 * math.atan(half / height)
    camera = world._scene.add_camera("overhead", size, size, fovy, 0.1, 50.0)
    # look down (-z) with image up = +x: pitch 90° down, then the image's up is the room's +x
    camera.entity.set_pose(sapien.Pose([0.0, 0.0, height], _quat((0.0, 1.0, 0.0), math.pi / 2)))
    world._scene.update_render()
    camera.take_picture()
    return np.clip(np.rint(camera.get_picture("Color")[..., :3] * 255.0), 0, 255).astype(np.uint8)


def overhead_pixel(x: float, y: float, size: int = 512, height: float = 9.0) -> tuple[float, float]:
    """Room (x, y) at floor level → (column, row) in `overhead_view` (pinhole projection)."""
    half = ROOM_HALF + 0.1
    scale = (size / 2) / half  # pixels per metre at floor level
    return size / 2 - y * scale, size / 2 - x * scale
