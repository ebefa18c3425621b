import numpy as np

from follow.sim.appearance import Appearance, PersonView, render_scene


def _view(u: float, distance_m: float, appearance: Appearance) -> PersonView:
    s = 400.0 / distance_m  # pixels per metre
    kp = np.full((18, 2), np.nan)
    foot_v = 200 + 0.6 * s
    kp[0] = (u, foot_v - 1.65 * s)
    kp[1] = (u, foot_v - 1.45 * s)
    kp[2], kp[5] = (u - 0.2 * s, foot_v - 1.4 * s), (u + 0.2 * s, foot_v - 1.4 * s)
    kp[8], kp[11] = (u - 0.1 * s, foot_v - 0.9 * s), (u + 0.1 * s, foot_v - 0.9 * s)
    kp[9], kp[12] = (u - 0.1 * s, foot_v - 0.45 * s), (u + 0.1 * s, foot_v - 0.45 * s)
    kp[10], kp[13] = (u - 0.1 * s, foot_v), (u + 0.1 * s, foot_v)
    return PersonView(kp, distance_m, s, appearance)


RED = Appearance((0, 0, 230), (120, 0, 0), (90, 130, 190), (20, 20, 20))
GREEN = Appearance((0, 230, 0), (0, 0, 0), (90, 130, 190), (20, 20, 20))


def test_shirt_colour_is_drawn_on_the_torso():
    img = render_scene((320, 480), 200, [_view(160, 4.0, RED)])
    torso = img[int(200 + 0.6 * 100 - 1.2 * 100), 160]
    assert tuple(torso) == (0, 0, 230)


def test_nearer_person_occludes_the_farther_one():
    far, near = _view(160, 5.0, GREEN), _view(160, 3.0, RED)
    for order in ([far, near], [near, far]):
        img = render_scene((320, 480), 200, order)
        v = int(200 + 0.6 * 80 - 1.2 * 80)  # the far person's chest
        assert tuple(img[v, 160]) == (0, 0, 230)


def test_random_appearances_are_deterministic():
    a = Appearance.random(np.random.default_rng(3))
    b = Appearance.random(np.random.default_rng(3))
    assert a == b


def test_a_frame_drawn_on_does_not_change_the_next_frames_background():
    """The background is drawn once per size, horizon and seed and copied for each frame:
    people drawn on one frame must not show in the next."""
    empty = render_scene((320, 480), 200, [])
    with_person = render_scene((320, 480), 200, [_view(160, 4.0, RED)])
    assert not np.array_equal(empty, with_person)
    assert np.array_equal(render_scene((320, 480), 200, []), empty)
    assert not np.array_equal(render_scene((320, 480), 200, [], seed=1), empty)
    assert not np.array_equal(render_scene((320, 480), 150, []), empty)
