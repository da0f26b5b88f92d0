"""map_server occupancy maps: PGM (P5 and P2), thresholds, and the cell <-> world geometry."""

from __future__ import annotations

import numpy as np
import pytest

from pedcal.errors import PedcalInputError
from pedcal.io.maps import read_occupancy_map, read_pgm


def write_map(tmp_path, pixels, *, ascii_pgm=False, origin=(-1.0, 2.0, 0.0), resolution=0.5, extra=""):
    h, w = pixels.shape
    pgm = tmp_path / "m.pgm"
    if ascii_pgm:
        body = "\n".join(" ".join(str(v) for v in row) for row in pixels)
        pgm.write_text(f"P2\n# a comment\n{w} {h}\n255\n{body}\n")
    else:
        pgm.write_bytes(f"P5\n# made by a test\n{w} {h}\n255\n".encode() + pixels.astype(np.uint8).tobytes())
    yml = tmp_path / "m.yaml"
    yml.write_text(f"image: m.pgm\nresolution: {resolution}\norigin: [{origin[0]}, {origin[1]}, {origin[2]}]\n"
                   f"negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\n{extra}")
    return yml


def small_pixels():
    # 3 rows x 4 cols: top row occupied (0), middle unknown (205), bottom free (254); one gray 128.
    px = np.array([[0, 0, 0, 0], [205, 205, 205, 205], [254, 254, 254, 128]])
    return px


@pytest.mark.parametrize("ascii_pgm", [False, True])
def test_small_map_classes_and_geometry(tmp_path, ascii_pgm):
    m = read_occupancy_map(write_map(tmp_path, small_pixels(), ascii_pgm=ascii_pgm))
    assert m.shape == (3, 4) and m.resolution_m == 0.5
    assert m.occupied[0].all() and not m.occupied[1:].any()
    assert m.unknown[1].all()
    assert m.free[2, :3].all() and m.unknown[2, 3]                 # p(128) = 0.498: unknown
    assert not (m.occupied & m.free).any() and (m.occupied | m.free | m.unknown).all()
    # Origin is the lower-left corner: the bottom-left cell's centre is origin + half a cell.
    np.testing.assert_allclose(m.cell_to_world([2, 0]), [-0.75, 2.25])
    np.testing.assert_allclose(m.cell_to_world([0, 3]), [0.75, 3.25])  # row 0 = top = max y
    assert m.world_to_cell([-0.75, 2.25]).tolist() == [2, 0]
    assert m.is_occupied([[0.9, 3.4], [0.9, 2.1], [50.0, 50.0]]).tolist() == [True, False, False]
    assert m.is_free([0.1, 2.1]) and not m.is_free([50.0, 50.0])


def test_rotated_origin_round_trip(tmp_path):
    m = read_occupancy_map(write_map(tmp_path, small_pixels(), origin=(1.0, -2.0, 0.7)))
    ij = np.array([[r, c] for r in range(3) for c in range(4)])
    np.testing.assert_array_equal(m.world_to_cell(m.cell_to_world(ij)), ij)
    # Moving along the rotated image x axis by one cell changes only the column.
    step = 0.5 * np.array([np.cos(0.7), np.sin(0.7)])
    assert (m.world_to_cell(m.cell_to_world([1, 1]) + step) == [1, 2]).all()


def test_negate_and_pure_threshold_rule(tmp_path):
    yml = write_map(tmp_path, small_pixels(), extra="")
    yml.write_text(yml.read_text().replace("negate: 0", "negate: 1"))
    m = read_occupancy_map(yml)
    assert m.free[0].all() and m.occupied[2, :3].all()
    yml = write_map(tmp_path, small_pixels())
    assert read_occupancy_map(yml, saver_unknown_value=None).free[1].all()   # map_server: 0.196 < 0.25


def test_real_turtlebot_map(shared_data):
    m = read_occupancy_map(shared_data / "turtlebot4_ros2_bag" / "mac_1st_floor_final.yaml")
    assert m.resolution_m == 0.03 and m.shape == (1706, 903)
    np.testing.assert_array_equal(m.origin_xy_yaw, [-1.12, -39.4, 0.0])
    # The image holds exactly three gray levels: 0 occupied, 205 unknown, 254 free.
    px, _ = read_pgm(shared_data / "turtlebot4_ros2_bag" / "mac_1st_floor_final.pgm")
    np.testing.assert_array_equal(m.occupied, px == 0)
    np.testing.assert_array_equal(m.free, px == 254)
    np.testing.assert_array_equal(m.unknown, px == 205)
    # The corners of the image are outside the building.
    assert m.unknown[0, 0] and m.unknown[-1, -1]
    free_xy = m.cell_to_world(np.argwhere(m.free))
    assert m.is_free(free_xy).all() and not m.is_occupied(free_xy).any()


@pytest.mark.parametrize("yaml_text,pgm,match", [
    ("resolution: 0.1\norigin: [0, 0, 0]\n", None, "image"),
    ("image: m.pgm\norigin: [0, 0, 0]\n", b"P5 1 1 255 \x00", "resolution"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0]\n", b"P5 1 1 255 \x00", "origin"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", b"P6 1 1 255 \x00", "not a PGM"),
    ("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", b"P5 4 4 255 \x00", "truncated"),
    ("image: missing.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n", None, "map image not found"),
])
def test_bad_maps(tmp_path, yaml_text, pgm, match):
    if pgm is not None:
        (tmp_path / "m.pgm").write_bytes(pgm)
    (tmp_path / "m.yaml").write_text(yaml_text)
    with pytest.raises(PedcalInputError, match=match):
        read_occupancy_map(tmp_path / "m.yaml")
