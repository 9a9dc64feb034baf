"""The SAPIEN arm in a room (docs/MODEL.md §2.3, §2.4): kinematics, camera, invisibility of the arm, rendering."""

from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest
from click.testing import CliRunner

from smspace.datagen.setups.arm import ArmWorld, planar_fk
from smspace.lake.dataset import Dataset

from .conftest import BIN, smgen

ARM_LAKE_ARGS = ("generate", "--setup", "arm", "--mode", "all", "--transitions", 1200, "--shard-size", 500, "--seed", 2)


@pytest.fixture(scope="module")
def world() -> ArmWorld:
    return ArmWorld(0)


@pytest.fixture(scope="module")
def arm_lake(tmp_path_factory):
    lake = tmp_path_factory.mktemp("arm_lake")
    result = smgen(*ARM_LAKE_ARGS, "--lake", lake)
    assert result.exit_code == 0, result.output
    return lake


def test_sapien_positions_equal_planar_forward_kinematics(world):
    rng = np.random.default_rng(0)
    m, p = world.sample_motors(rng, 2000)
    np.testing.assert_allclose(p, planar_fk(m), atol=5e-6)
    assert np.abs(m).max() <= 1 and np.linalg.norm(p, axis=1).max() <= 1.5 + 1e-5
    m_reg, p_reg = world.regular_sampling()
    assert m_reg.shape == (216, 3)
    np.testing.assert_allclose(p_reg, planar_fk(m_reg), atol=5e-6)
    assert len(np.unique(np.round(p_reg, 4), axis=0)) == 55  # docs/MODEL.md §2.3: 55 distinct positions


def test_six_motor_arm_kinematics():
    arm6 = ArmWorld(0, n_motor=6)
    m, p = arm6.sample_motors(np.random.default_rng(1), 2000)
    np.testing.assert_allclose(p, planar_fk(m), atol=5e-6)
    # negative prismatic lengths flip their segment: m5 = m6 = -1 with straight joints folds back
    straight = np.array([[0, 0, 0, 0, -1, -1]], float)
    np.testing.assert_allclose(arm6.positions(straight), [[0.0, 0.0]], atol=5e-6)
    np.testing.assert_allclose(arm6.positions(np.array([[0, 0, 0, 0, 1, 1.0]])), [[1.5, 0.0]], atol=5e-6)


def test_the_arm_never_appears_in_the_image(world):
    import sapien

    bare = ArmWorld(0, arm_visuals=False)
    rng = np.random.default_rng(3)
    m = np.vstack([rng.uniform(-1, 1, (300, 3)), [[0, 1, 1], [0.5, -1, 0], [1, 1, 1], [0, 0.9, 0.2]]])
    p = world.positions(m)
    # folded arms put links right in front of and around the camera
    np.testing.assert_array_equal(world.render(p), bare.render(p))
    visual_links = [
        link
        for link in world._articulation.links
        if link.entity.find_component_by_type(sapien.render.RenderBodyComponent) is not None
    ]
    assert len(visual_links) >= 3, "the comparison is only meaningful if the arm has visuals"


def test_frames_vary_and_are_not_constant(world):
    rng = np.random.default_rng(4)
    xy = rng.uniform(-2.5, 2.5, (64, 2))
    frames = world.render(xy)
    assert frames.dtype == np.uint8 and frames.shape == (64, 16, 16, 3)
    assert all(f.std() > 5 for f in frames)
    assert len(np.unique(frames.reshape(64, -1), axis=0)) == 64
    np.testing.assert_array_equal(world.render(xy[:8]), frames[:8])  # deterministic


def test_moving_the_room_by_d_equals_moving_the_camera_by_minus_d(world):
    camera = np.array([[0.3, -0.7], [1.2, 0.4], [-1.0, -1.0]])
    d = (0.6, -0.45)
    moved_room = world.render(camera, room_offset=d)
    moved_camera = world.render(camera - np.array(d))
    np.testing.assert_allclose(moved_room.astype(int), moved_camera.astype(int), atol=1)
    assert np.mean(moved_room == moved_camera) > 0.99
    # and the room is back in place afterwards
    np.testing.assert_array_equal(world.render(camera), world.render(camera))


def test_rooms_come_from_the_seed():
    a, b, c = ArmWorld(5).room, ArmWorld(5).room, ArmWorld(6).room
    np.testing.assert_array_equal(a.floor_texture, b.floor_texture)
    assert a.objects == b.objects and a.objects != c.objects
    assert len(a.objects) == 16 and {o.shape for o in a.objects} <= {"box", "sphere", "cylinder", "capsule"}
    cells = [(int(np.floor(o.x / 1.75)), int(np.floor(o.y / 1.75))) for o in a.objects]
    assert len(set(cells)) == 16  # one object per cell of the 4×4 grid


def test_modes_validate_and_camera_stays_inside_the_walls(arm_lake):
    ids = ["arm-seed2-MEM", "arm-seed2-MM", "arm-seed2-MME"]
    result = smgen("validate", "--lake", arm_lake, *ids)
    assert result.exit_code == 0, result.output
    for ds_id in ids:
        tr = Dataset.open(ds_id, arm_lake).read_all()
        assert tr.s_t.shape == (1200, 16, 16, 3) and tr.s_t.dtype == np.uint8
        for p, shift in ((tr.p_t, tr.shift_t), (tr.p_t1, tr.shift_t1)):
            assert np.abs(p + shift).max() < 3.5 - 0.2
        np.testing.assert_allclose(tr.p_t, planar_fk(tr.m_t), atol=5e-6)
    mm = Dataset.open("arm-seed2-MM", arm_lake).read_all()
    assert np.all(mm.shift_t == 0)
    # what rendered the pixels, recorded by the worker that rendered them
    software = Dataset.open("arm-seed2-MM", arm_lake).manifest.software
    assert software["sapien"] == "3.0.3" and software["vulkan_device"] not in ("", "unknown")
    assert software["vulkan_driver"].startswith(("lavapipe, Mesa 25.", "NVRM", "the system's Vulkan driver"))


def test_same_bytes_with_one_and_two_workers(arm_lake, tmp_path):
    args = [*ARM_LAKE_ARGS, "--lake", tmp_path, "--workers", 2]
    proc = subprocess.run([str(BIN / "smgen"), *map(str, args)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    for mode in ("MEM", "MM", "MME"):
        a, b = arm_lake / f"arm-seed2-{mode}", tmp_path / f"arm-seed2-{mode}"
        names = sorted(p.name for p in a.iterdir())
        assert names == sorted(p.name for p in b.iterdir())
        for name in names:
            assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_no_vulkan_device_is_a_clear_error(tmp_path):
    env = {**os.environ, "VK_ICD_FILENAMES": str(tmp_path / "missing_icd.json")}
    proc = subprocess.run(
        [
            str(BIN / "smgen"),
            "generate",
            "--setup",
            "arm",
            "--mode",
            "MM",
            "--transitions",
            "10",
            "--lake",
            str(tmp_path / "lake"),
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "setup-vulkan.sh" in proc.stderr
    assert not (tmp_path / "lake").exists()


def test_preview_writes_pictures_of_a_world_and_of_a_dataset(tmp_path):
    from PIL import Image

    from .conftest import SAMPLES

    out = smgen("preview", "--setup", "arm", "--seed", 1, "--out", tmp_path / "world", "--frames", 16)
    assert out.exit_code == 0, out.output
    room = np.asarray(Image.open(tmp_path / "world" / "room.png"))
    frames = np.asarray(Image.open(tmp_path / "world" / "frames.png"))
    assert room.shape == (512, 512, 3) and room.std() > 10
    assert frames.shape[0] > 200 and frames.std() > 10
    out = smgen("preview", "arm-seed0-MM", "--lake", SAMPLES, "--out", tmp_path / "ds")
    assert out.exit_code == 0 and (tmp_path / "ds" / "frames.png").exists()
    out = smgen("preview", "grid-seed0-MM", "--lake", SAMPLES, "--out", tmp_path / "grid")
    assert out.exit_code == 0 and (tmp_path / "grid" / "sensory_table.png").exists()
    assert smgen("preview", "--out", tmp_path / "x").exit_code == 2


def test_training_on_images(tmp_path):
    from smspace.cli import smtrain as smtrain_main
    from smspace.train.run_dir import RunView

    from .conftest import SAMPLES

    result = CliRunner().invoke(
        smtrain_main,
        [
            "fit",
            "arm-seed0-MME",
            "--lake",
            str(SAMPLES),
            "--steps",
            "200",
            "--eval-every",
            "100",
            "--out",
            str(tmp_path / "run"),
        ],
    )
    assert result.exit_code == 0, result.output
    rows = RunView.open(tmp_path / "run").metrics()
    assert rows[-1]["eval_loss"] < 0.7 * rows[0]["eval_loss"]
    h, p = RunView.open(tmp_path / "run").embeddings(200)
    assert h.shape == (216, 3) and p.shape == (216, 2)
