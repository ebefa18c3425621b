import json
import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from follow.camera import CameraFileError, CameraModel, CameraPose, undistort_points


def make_camera(pitch_deg=10.0, roll_deg=0.0, yaw_deg=0.0, dist=None, height_m=0.6):
    pose = CameraPose(
        height_m=height_m,
        pitch_rad=math.radians(pitch_deg),
        roll_rad=math.radians(roll_deg),
        yaw_rad=math.radians(yaw_deg),
        x_m=0.1,
        y_m=-0.05,
    )
    return CameraModel.from_fov((640, 360), 70.0, pose, dist=dist)


def test_point_straight_ahead_projects_on_the_centre_column():
    cam = make_camera(pitch_deg=0.0)
    cam = CameraModel.from_fov((640, 360), 70.0, CameraPose(height_m=0.6))
    u, v = cam.project(np.array([5.0, 0.0, 0.6]))
    assert u == pytest.approx(cam.K[0, 2])
    assert v == pytest.approx(cam.K[1, 2])
    # a point to the left (y > 0) appears left in the image, a lower one appears lower
    assert cam.project(np.array([5.0, 1.0, 0.6]))[0] < u
    assert cam.project(np.array([5.0, 0.0, 0.0]))[1] > v


@pytest.mark.parametrize("dist", [None, np.array([-0.2, 0.05, 0.001, -0.001, 0.0])])
@pytest.mark.parametrize("pitch_deg,roll_deg,yaw_deg", [(0, 0, 0), (15, 3, -5), (25, -2, 10)])
def test_ground_round_trip(dist, pitch_deg, roll_deg, yaw_deg):
    cam = make_camera(pitch_deg, roll_deg, yaw_deg, dist)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(2, 20, 200), rng.uniform(-3, 3, 200), np.zeros(200)])
    px = cam.project(pts)
    visible = cam.in_image(px)
    assert visible.sum() > 50
    back = cam.back_project_to_ground(px[visible])
    np.testing.assert_allclose(back, pts[visible, :2], atol=1e-6 * 20)


@pytest.mark.parametrize("dist", [None, np.array([-0.2, 0.05, 0.001, -0.001, 0.0])])
def test_ground_round_trip_with_a_skewed_camera_matrix(dist):
    # The file may hold a skew K[0][1] (projection applies it); OpenCV's undistortPoints
    # ignores it, so with distortion a ground point came back from its pixel 7 cm off.
    cam = make_camera(15, 3, -5, dist)
    K = cam.K.copy()
    K[0, 1] = 20.0
    cam = CameraModel(K, cam.dist, cam.image_size, cam.pose)
    pts = np.array([[2.0, 0.8, 0.0], [4.0, -1.0, 0.0], [8.0, 1.5, 0.0]])
    px = cam.project(pts)
    assert cam.in_image(px).all()
    np.testing.assert_allclose(cam.back_project_to_ground(px), pts[:, :2], atol=1e-6)


def test_plane_at_height_round_trip():
    cam = make_camera(12, 1, 0, np.array([-0.1, 0.01, 0, 0, 0]))
    p = np.array([[6.0, 0.5, 1.5], [3.0, -1.0, 1.2]])
    for point in p:
        back = cam.back_project_to_plane(cam.project(point), point[2])
        np.testing.assert_allclose(back, point, atol=1e-6)


def test_pixels_above_horizon_have_no_ground_point():
    cam = make_camera(pitch_deg=5.0)
    horizon = cam.horizon_line()
    a, b, c = horizon
    u = 320.0
    v_h = -(a * u + c) / b
    above, below = np.array([u, v_h - 5.0]), np.array([u, v_h + 5.0])
    assert cam.ground_point(above) is None
    assert np.isnan(cam.back_project_to_ground(above)).all()
    g = cam.ground_point(below)
    assert g is not None and g[0] > 5.0  # far away, just under the horizon
    assert a * below[0] + b * below[1] + c > 0 > a * above[0] + b * above[1] + c
    assert cam.is_below_horizon(np.array([below, above])).tolist() == [True, False]


def test_a_pixel_on_the_horizon_has_no_ground_point_and_no_warning():
    """The ray through it runs parallel to the floor: NaN, quietly (no RuntimeWarning
    from numpy printed among a command's output)."""
    cam = make_camera(pitch_deg=0.0)
    on_horizon = np.array([100.0, cam.K[1, 2]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(cam.back_project_to_ground(on_horizon)).all()
        assert cam.ground_point(on_horizon) is None


def test_points_behind_camera_project_to_nan():
    cam = make_camera()
    assert np.isnan(cam.project(np.array([-2.0, 0.0, 0.0]))).all()


def test_scaled_camera_keeps_geometry():
    cam = make_camera(dist=np.array([-0.2, 0.05, 0, 0, 0]))
    small = cam.scaled(320, 180)
    pts = np.array([[4.0, 0.3, 0.0], [8.0, -1.0, 1.4]])
    big_px, small_px = cam.project(pts), small.project(pts)
    np.testing.assert_allclose((small_px + 0.5) * 2.0 - 0.5, big_px, atol=1e-9)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_save_load_round_trip(tmp_path, suffix):
    cam = make_camera(12, 1, 2, np.array([-0.2, 0.05, 0.001, -0.001, 0.01]))
    path = tmp_path / f"cam{suffix}"
    cam.save(path)
    loaded = CameraModel.load(path)
    np.testing.assert_allclose(loaded.K, cam.K)
    np.testing.assert_allclose(loaded.dist, cam.dist)
    assert loaded.pose == cam.pose and loaded.image_size == cam.image_size


def test_malformed_camera_file_names_the_field(tmp_path):
    cam = make_camera()
    data = cam.to_dict()
    del data["pose"]["height_m"]
    path = tmp_path / "cam.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match="pose.height_m"):
        CameraModel.load(path)
    data = cam.to_dict()
    data["camera_matrix"] = [[1, 2], [3, 4]]
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match="camera_matrix"):
        CameraModel.load(path)
    data = cam.to_dict()
    data["pose"]["pitch_rad"] = "steep"
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match="pose.pitch_rad"):
        CameraModel.load(path)
    path.write_text("{not json")
    with pytest.raises(CameraFileError, match="not valid"):
        CameraModel.load(path)
    with pytest.raises(CameraFileError, match="cannot read"):
        CameraModel.load(tmp_path / "missing.yaml")


@settings(max_examples=100, deadline=None)
@given(
    u=st.floats(-100, 740, allow_nan=False),
    v=st.floats(-100, 460, allow_nan=False),
    pitch=st.floats(-10, 40),
)
def test_back_projection_is_in_front_or_nan(u, v, pitch):
    cam = make_camera(pitch_deg=pitch)
    g = cam.back_project_to_ground(np.array([u, v]))
    if not np.isnan(g).any():
        rel = g - cam.position_base[:2]
        forward = np.array([math.cos(cam.pose.yaw_rad), math.sin(cam.pose.yaw_rad)])
        assert rel @ forward > 0
        np.testing.assert_allclose(cam.project(np.append(g, 0.0)), [u, v], atol=1e-4)


def test_camera_for_another_image_size():
    cam = make_camera()
    assert cam.for_image_size(640, 360) is cam
    half = cam.for_image_size(320, 180)
    np.testing.assert_allclose(half.K, cam.scaled(320, 180).K)
    with pytest.raises(ValueError, match="another aspect ratio"):
        cam.for_image_size(640, 480)


@pytest.mark.parametrize(
    "field,value,match",
    [
        ("pitch_rad", 3.0, "pitch_rad = 3.0 is not a possible mounting"),
        ("height_m", True, "'pose.height_m' must be a number, got True"),
        ("height_m", "1.0", "'pose.height_m' must be a number, got '1.0'"),
        ("height_m", -0.5, "height_m = -0.5 is not a possible mounting"),
        ("height_m", 1000.0, "height_m = 1000.0"),
        ("roll_rad", -4.0, "roll_rad"),
        ("pitch_rad", float("nan"), "pitch_rad"),
    ],
)
def test_impossible_camera_poses_are_refused_naming_the_field(tmp_path, field, value, match):
    data = CameraModel.from_fov((640, 480), 70.0, CameraPose(height_m=1.0)).to_dict()
    data["pose"][field] = value
    with pytest.raises(CameraFileError, match=match):
        CameraModel.from_dict(data, source="cam.yaml")


def test_a_wide_lens_polynomial_never_folds_points_outside_the_view_into_the_image():
    """Fitted to the image, k1-k3 turn back beyond it: a bearing past the left edge
    must project farther left, never back onto the image."""
    camera = CameraModel.from_fov((640, 480), 90.0, CameraPose(height_m=0.9),
                                  dist=np.array([-0.35, 0.15, 0.0, 0.0, -0.03]))  # fmt: skip
    edge = camera.pixel_rays_base(np.array([[-0.5, 239.5]]))[0]
    edge_deg = np.degrees(np.arctan2(edge[1], edge[0]))
    bearings = np.radians(np.arange(edge_deg + 1.0, 85.0, 1.0))
    points = np.column_stack([3 * np.cos(bearings), 3 * np.sin(bearings), np.full(len(bearings), 0.9)])
    uv = camera.project(points)
    assert not camera.in_image(uv).any()
    assert (np.diff(uv[:, 0]) < 0).all()  # ever farther left
    inside = camera.project(np.array([3.0, 0.5, 0.9]))  # within the view: unchanged
    assert camera.in_image(inside)[0]


@pytest.mark.parametrize(
    "calibration, placeholder",
    [
        ({"pose": "placeholder: measure it with `follow-calib ground`"}, True),
        ({"pose": "  Placeholder (edited by hand)"}, True),
        ({"pose": "follow-calib ground"}, False),
        ({"pose": "follow-calib import-tsai View_001.xml"}, False),
        ({"intrinsics": "follow-calib intrinsics"}, False),
        ({"pose": ["placeholder"]}, False),
        (None, False),
    ],
)
def test_a_placeholder_pose_is_told_by_the_calibration_notes(tmp_path, calibration, placeholder):
    """A file without notes (by hand, `CameraModel.save`) or with a measured pose is
    taken as measured, in YAML and JSON alike; a file that cannot be read is no
    placeholder (`CameraModel.load` reports it)."""
    from follow.camera import check_pose_measured, has_placeholder_pose

    data = make_camera().to_dict()
    if calibration is not None:
        data["calibration"] = calibration
    for name in ("cam.yaml", "cam.json"):
        path = tmp_path / name
        path.write_text(json.dumps(data))  # JSON is YAML too
        assert has_placeholder_pose(path) is placeholder
        warned = []
        check_pose_measured(path, False, warned.append)
        assert len(warned) == int(placeholder)
        if placeholder:
            with pytest.raises(ValueError, match=f"camera file {path}: .*follow-calib ground"):
                check_pose_measured(path, True, warned.append)
        else:
            check_pose_measured(path, True, warned.append)
    assert not has_placeholder_pose(tmp_path / "missing.yaml")
    (tmp_path / "broken.yaml").write_text("calibration: [")
    assert not has_placeholder_pose(tmp_path / "broken.yaml")


@pytest.mark.parametrize(
    "calibrated_size, file_size, principal_px, off",
    [
        ((640, 480), (1280, 960), None, "25 % of the width and 25 % of the height"),
        ((640, 480), (1920, 1440), None, "33 % of the width"),
        ((1280, 960), (640, 480), (633.2, 470.8), "49 % of the width"),  # inside the image
        ((1920, 1080), (640, 360), None, "outside the 640x360 image"),
    ],
)
def test_a_camera_matrix_for_another_image_size_is_refused(
    calibrated_size, file_size, principal_px, off
):
    """Only a principal point outside the image was refused: a 640x480 matrix in a file
    for 1280x960 (its principal point a quarter of the way in) loaded, and placed a
    person 3 m ahead at 0.8 m."""
    data = CameraModel.from_fov(calibrated_size, 70.0, CameraPose(0.8)).to_dict()
    data["image_width"], data["image_height"] = file_size
    if principal_px is not None:
        data["camera_matrix"][0][2], data["camera_matrix"][1][2] = principal_px
    with pytest.raises(CameraFileError, match=f"principal point .* lies {off}.*: a camera_matrix "
                       "for another image size"):  # fmt: skip
        CameraModel.from_dict(data, source="cam.yaml")


def test_the_cameras_the_project_ships_have_their_principal_point_in_bounds(data_path):
    """The principal point bound keeps every camera in use: PETS's (Tsai import, 7.7 % of
    the width off the centre), the demo's, and one 19 % off."""
    from calib.tsai import TsaiCamera
    from follow.camera import MAX_PRINCIPAL_POINT_OFFSET
    from follow.sim.demo import DEMO_CAMERA

    pets, _ = TsaiCamera.from_xml(data_path("pets2009_s2l1/View_001.xml")).to_camera_model()
    assert abs(pets.K[0, 2] - 383.5) / 768 == pytest.approx(0.077, abs=0.001)
    assert MAX_PRINCIPAL_POINT_OFFSET >= 2 * 0.077
    for camera in (pets, DEMO_CAMERA.camera(), DEMO_CAMERA.detection_camera()):
        CameraModel.from_dict(camera.to_dict())
    data = CameraModel.from_fov((640, 480), 70.0, CameraPose(0.8)).to_dict()
    data["camera_matrix"][0][2] = 319.5 + 0.19 * 640
    data["camera_matrix"][1][2] = 239.5 - 0.19 * 480
    CameraModel.from_dict(data)


WIDE_LENS = np.array([-0.35, 0.15, 0.0, 0.0, -0.03])  # turns back inside the image's corners


@pytest.mark.parametrize(
    "fov_deg, dist",
    [
        (90.0, WIDE_LENS),
        (90.0, WIDE_LENS + [0.0, 0.0, 0.003, -0.002, 0.0]),
        (100.0, np.array([-0.32, 0.09, 0.0, 0.0, -0.009])),
    ],
)
def test_pixels_past_the_lens_fold_round_trip_through_their_rays(fov_deg, dist):
    """project() lets the radius grow on past the fold; back-projection followed the
    polynomial instead, and gave corner pixels rays up to 118 px off (ground points 0.5 m
    off) where it should invert that growth."""
    camera = CameraModel.from_fov((640, 480), fov_deg, CameraPose(0.9, math.radians(10)),
                                  dist=dist)  # fmt: skip
    u, v = np.meshgrid(np.linspace(-0.5, 639.5, 81), np.linspace(-0.5, 479.5, 61))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = camera.pixel_rays_base(pixels)
    assert np.isfinite(rays).all()
    again = camera.project(camera.position_base + 2.0 * rays)
    np.testing.assert_allclose(again, pixels, atol=0.1)
    corners = np.array([[-0.5, -0.5], [639.5, -0.5], [-0.5, 479.5], [639.5, 479.5]])
    np.testing.assert_allclose(camera.project(camera.position_base + camera.pixel_rays_base(
        corners)), corners, atol=1e-3)  # fmt: skip
    # Floor points seen in the lower corners come back to where they were.
    floor = np.array([[0.55, 1.42, 0.0], [0.55, -1.42, 0.0], [1.06, -1.91, 0.0]])
    seen = camera.in_image(camera.project(floor))
    back = camera.back_project_to_ground(camera.project(floor[seen]))
    np.testing.assert_allclose(back, floor[seen, :2], atol=0.01)
    below = camera.is_below_horizon(camera.project(floor[seen]))
    assert below.all()


def test_a_pixel_whose_undistortion_goes_astray_has_no_ray(monkeypatch):
    """Undistortion iterates and may settle on a point that does not project onto the
    pixel: that pixel has no ray (NaN, no ground point), not a ray through elsewhere."""
    camera = make_camera(dist=np.array([-0.2, 0.05, 0.001, -0.001, 0.0]))
    pixels = np.array([[100.0, 300.0], [320.0, 300.0]])
    good = camera.back_project_to_ground(pixels)
    assert np.isfinite(good).all()

    def astray(points, K, dist, criteria):
        out = np.array(undistort_points(points, K, dist, criteria))
        out[0] += 0.05  # 20 px off
        return out

    monkeypatch.setattr("follow.camera.undistort_points", astray)
    assert np.isnan(camera.pixel_rays_base(pixels)[0]).all()
    ground = camera.back_project_to_ground(pixels)
    assert np.isnan(ground[0]).all()
    np.testing.assert_allclose(ground[1], good[1])
    assert camera.is_below_horizon(pixels).tolist() == [False, True]


@pytest.mark.parametrize("p1, p2", [(0.2, 0.0), (0.0, 0.2), (0.5, 0.0), (0.1, -0.1)])
def test_tangential_distortion_that_folds_the_image_is_refused(p1, p2):
    """p1 = 0.2 (for 0.002) loaded, though the image folds over itself and rays came back
    hundreds of pixels from their pixels."""
    data = CameraModel.from_fov((640, 480), 75.0, CameraPose(0.8, 0.17)).to_dict()
    data["distortion"] = [-0.18, 0.04, p1, p2, 0.0]
    with pytest.raises(CameraFileError, match=rf"cam.yaml: camera distortion \[-0.18, 0.04, "
                       rf"{p1}, {p2}, 0.0\] folds the image over itself .*tangential p1 {p1:g}, "
                       rf"p2 {p2:g}"):  # fmt: skip
        CameraModel.from_dict(data, source="cam.yaml")


@pytest.mark.parametrize(
    "fov_deg, dist",
    [
        (75.0, [-0.18, 0.04, 0.001, -0.0005, 0.0]),
        (75.0, [-0.18, 0.04, 0.05, 0.0, 0.0]),  # strong, but no fold
        (90.0, (WIDE_LENS + [0.0, 0.0, 0.005, 0.005, 0.0]).tolist()),  # folds past the edge
        (75.0, [-0.2, 0.05, 0.001, -0.001, 0.0, 0.1, 0.01, 0.0]),
    ],
)
def test_real_tangential_distortion_loads(fov_deg, dist):
    data = CameraModel.from_fov((640, 480), fov_deg, CameraPose(0.8, 0.17)).to_dict()
    data["distortion"] = dist
    assert CameraModel.from_dict(data).dist.tolist() == dist


@pytest.mark.parametrize("number", [np.float64, np.float32])
@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_a_pose_of_numpy_numbers_can_be_saved(tmp_path, number, suffix):
    """It was accepted, then YAML (and JSON, for float32) could not write it."""
    pose = CameraPose(number(0.8), number(0.2), number(0.01), number(0.0), number(0.1))
    assert all(type(getattr(pose, name)) is float for name in ("height_m", "pitch_rad", "y_m"))
    camera = CameraModel.from_fov((640, 480), 70.0, pose)
    camera.save(tmp_path / f"cam{suffix}")
    assert CameraModel.load(tmp_path / f"cam{suffix}").pose == pose
