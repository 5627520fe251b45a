"""Correspondence and confidence (eqs. 1-7) on synthetic and rendered images."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from calib_free.correspondence.search import (CorrespondenceError, CorrespondenceParams, EyeMatch, FixationMatch,
                                       _backward_distance, correspondence_map, foveal_patch, match_eye)
from calib_free.correspondence.stereo import stereo_inconsistency
from calib_free.correspondence.disparity import foveal_disparity
from headctl.service.head import joints_of
from calib_free.sim.head_model import HeadModel, JointLimits
from drivers.sim.scene import StereoRenderer, shared_scene
from drivers.sim.truth import foveal_point, hidden_from, texture_at
from headctl.experiments.saccades import accuracy, saccade_cases, scored

W, H = 320, 240
PAPER = CorrespondenceParams.profile_values("paper")


def texture(seed: int = 0, shape: tuple[int, int] = (600, 800)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.random(shape, dtype=np.float32) * 255, (0, 0), 2.0)
    return cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX)


def view(tex: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """The W x H image whose top-left pixel is texel (x0, y0)."""
    return tex[y0:y0 + H, x0:x0 + W].copy()


def test_a_pure_shift_is_found_exactly():
    tex = texture()
    pre = view(tex, 200, 150)
    for dx, dy in ((37, -21), (-100, 60), (120, 95), (-140, -100)):
        post = view(tex, 200 + dx, 150 + dy)  # the head turned: pre's (cx+dx, cy+dy) is now at the fovea
        m = match_eye(pre, post, CorrespondenceParams())
        assert m.x == pytest.approx((W - 1) / 2 + dx, abs=0.2)
        assert m.y == pytest.approx((H - 1) / 2 + dy, abs=0.2)
        assert m.c1 > 0.99 and m.c2 > 0.99


def test_coarse_to_fine_search_finds_the_same_place_at_640():
    tex = texture(1, (900, 1200))
    pre = tex[100:580, 100:740]
    post = tex[100 + 57:580 + 57, 100 - 83:740 - 83]
    full = match_eye(pre, post, CorrespondenceParams(pyramid_levels=0))
    coarse = match_eye(pre, post, CorrespondenceParams())  # 640 px wide: one pyramid level
    assert (coarse.x, coarse.y) == pytest.approx((full.x, full.y), abs=0.3)
    assert coarse.x == pytest.approx(319.5 - 83, abs=0.3) and coarse.y == pytest.approx(239.5 + 57, abs=0.3)


def test_the_factors_pick_the_true_place_where_plain_ncc_picks_a_look_alike():
    """Paper fig. 3: in the periphery the fovea's patch appears shrunk; NCC alone prefers an
    unshrunk look-alike of different brightness and contrast, the mean/variance factors do not."""
    rng = np.random.default_rng(5)
    post = (rng.random((H, W)) * 60 + 100).astype(np.float32)
    fovea = cv2.GaussianBlur(rng.random((20, 20), dtype=np.float32) * 200, (0, 0), 1.0) + 30
    post[110:130, 150:170] = fovea
    pre = (rng.random((H, W)) * 60 + 100).astype(np.float32)
    pre = cv2.GaussianBlur(pre, (0, 0), 3)
    # the true place: the same surface, compressed to 75 % as the periphery of a fish-eye does
    shrunk = cv2.resize(fovea, (15, 15), interpolation=cv2.INTER_AREA)
    pre[40:60, 40:60] = cv2.resize(shrunk, (20, 20), interpolation=cv2.INTER_LINEAR)
    pre[42:57, 42:57] = shrunk
    # a look-alike: the same pattern, darker and with less contrast (NCC ignores both)
    pre[180:200, 250:270] = 0.3 * fovea + 20
    plain = match_eye(pre, post, CorrespondenceParams.profile_values("paper", use_factors=False))
    weighted = match_eye(pre, post, PAPER)
    assert abs(plain.x - 259.5) < 2 and abs(plain.y - 189.5) < 2  # NCC alone: the look-alike
    assert abs(weighted.x - 49.5) < 4 and abs(weighted.y - 49.5) < 4  # with f1 f2: the truth


def test_correspondence_map_is_bounded():
    tex = texture(2)
    pre, post = view(tex, 100, 100), view(tex, 130, 90)
    cmap = correspondence_map(pre, foveal_patch(post, (20, 20)), CorrespondenceParams())
    assert cmap.shape == (H - 19, W - 19)
    assert np.all(np.abs(cmap) <= 1.0 + 1e-5)  # eq. 4 may treat c_max as a correlation


def test_confidence_follows_eqs_4_and_6():
    tex = texture(3)
    pre, post = view(tex, 100, 100), view(tex, 160, 130)
    m = match_eye(pre, post, CorrespondenceParams.profile_values("paper", min_correlation=0.2))
    c_s, c_t = 10 / (1 - 0.2), (1 + 0.2) / 2
    assert m.c1 == pytest.approx(1 / (1 + np.exp(-c_s * (m.c_max - c_t))))
    assert m.c2 == pytest.approx(1 / (1 + m.competitors))
    assert m.confidence == pytest.approx(m.c1 * m.c2)  # the paper's per-eye figure
    fm = FixationMatch(m, m)
    assert fm.confidence == pytest.approx((m.c1 * m.c2) ** 2)
    assert fm.position[2] == 0.0


def test_foveal_disparity_has_the_sign_of_d():
    tex = texture(4)
    left = view(tex, 200, 150)
    right = view(tex, 195, 150)  # the right eye sees the left fovea's content 5 px right of its centre
    d, score = foveal_disparity(left, right)
    assert d == pytest.approx(5.0, abs=0.1) and score > 0.99
    d, _ = foveal_disparity(left, view(tex, 212, 150))
    assert d == pytest.approx(-12.0, abs=0.1)


def test_bad_images_are_named():
    with pytest.raises(CorrespondenceError, match="differ"):
        match_eye(np.zeros((240, 320)), np.zeros((120, 160)), CorrespondenceParams())
    with pytest.raises(CorrespondenceError, match="grey"):
        match_eye(np.zeros((240, 320, 4)), np.zeros((240, 320, 4)), CorrespondenceParams())
    with pytest.raises(ValueError, match="patch_size"):
        CorrespondenceParams(patch_size=(2, 2))


def test_stereo_inconsistency_catches_rows_that_disagree():
    tex = texture(6)
    left, right = view(tex, 200, 150), view(tex, 190, 150)  # pre-fixation disparity +10 everywhere
    good = FixationMatch(EyeMatch(100, 80, 0.9, 1, 1, 0), EyeMatch(110, 80, 0.9, 1, 1, 0))
    assert stereo_inconsistency(good, left, right, CorrespondenceParams()) == ""
    rows = FixationMatch(EyeMatch(100, 80, 0.9, 1, 1, 0), EyeMatch(110, 90, 0.9, 1, 1, 0))
    assert "rows differ by 10.0 px" in stereo_inconsistency(rows, left, right, CorrespondenceParams())
    repeat = FixationMatch(EyeMatch(100, 80, 0.9, 1, 1, 0), EyeMatch(124, 80, 0.9, 1, 1, 0))
    assert "d* = 24.0 px" in stereo_inconsistency(repeat, left, right, CorrespondenceParams())


def test_stereo_inconsistency_refuses_a_d_that_a_repeat_along_the_row_could_give():
    """On a texture repeating along the rows, the eyes can verge on different repeats: each eye's
    match is right for what it sees, the pre-fixation pair agrees with d*, and d* is wrong."""
    rng = np.random.default_rng(0)
    period = 40
    tile = cv2.GaussianBlur(rng.random((240, period)).astype(np.float32), (0, 0), 2.0)
    stripes = cv2.normalize(np.tile(tile, (1, 10)), None, 0, 255, cv2.NORM_MINMAX)
    left, right = stripes[:, 20:340].copy(), stripes[:, 10:330].copy()  # d = +10, and +10 + 40 k
    for d_star in (10.0, 50.0):
        match = FixationMatch(EyeMatch(150, 120, 0.9, 1, 1, 0), EyeMatch(150 + d_star, 120, 0.9, 1, 1, 0))
        assert "repeats along its rows" in stereo_inconsistency(match, left, right, CorrespondenceParams())
    tex = texture(6)
    unique_left, unique_right = view(tex, 200, 150), view(tex, 190, 150)
    good = FixationMatch(EyeMatch(150, 120, 0.9, 1, 1, 0), EyeMatch(160, 120, 0.9, 1, 1, 0))
    assert stereo_inconsistency(good, unique_left, unique_right, CorrespondenceParams()) == ""


# --- on rendered fish-eye images of the simulated room -----------------------------------
@pytest.fixture(scope="module")
def rendered_cases():
    """Pre/post pairs of random saccades (+-15 deg) with the true pre-fixation position of what
    lands on the left fovea, its surface's texture kind, and sensor noise of 2 grey levels."""
    model = HeadModel.default(limits=JointLimits(vergence=(1.0, 20.0)))
    scene = shared_scene(0, False)
    rng = np.random.default_rng(11)
    cases = []
    with StereoRenderer(model, scene, parallel=False) as renderer:
        while len(cases) < 160:
            pre = rng.uniform(model.limits.low, model.limits.high)
            post = model.limits.clamp(pre + np.r_[rng.uniform(-15, 15, 2), 0.0])
            target = foveal_point(model, scene, joints_of(post))
            r, seen = model.image_position(target[None, :], pre)
            (_, eye), _ = model.eye_frames(pre)
            if not seen[0] or hidden_from(scene, eye, target, 0.01):
                continue  # out of view or occluded before the saccade: no right answer
            kind = texture_at(scene, target)
            images = [renderer.render(joints_of(p))[0] for p in (pre, post)]
            noisy = [np.clip(im + rng.normal(0, 2.0, im.shape), 0, 255).astype(np.uint8) for im in images]
            cases.append((noisy[0], noisy[1], r[0, :2], kind))
    return cases


def test_rendered_correspondence_is_within_a_pixel_on_rich_texture(rendered_cases):
    """Without the centre-weighted relocation this is 92-94 %: the periphery's compression
    skews the foveal patch and pulls the plain NCC peak by a pixel or so."""
    errors = [np.hypot(*(np.array([m.x, m.y]) - truth))
              for pre, post, truth, kind in rendered_cases if kind == "rich"
              for m in [match_eye(pre, post, CorrespondenceParams())]]
    assert len(errors) > 80
    within = np.mean(np.array(errors) <= 1.0)
    assert within >= 0.95, f"{within:.1%} of rich-texture patches within 1 px"  # issue 5's figure


def test_nearly_uniform_patches_get_far_less_confidence_than_textured(rendered_cases):
    """Paper fig. 4: 0.93 on a detailed patch, 0.39 on one with little structure; in either
    profile (the paper's c1 c2, the default's own confidence)."""
    for params in (PAPER, CorrespondenceParams()):
        conf = {"rich": [], "uniform": []}
        for pre, post, _, kind in rendered_cases:
            if kind in conf:
                conf[kind].append(match_eye(pre, post, params).confidence)
        assert len(conf["uniform"]) >= 10
        assert np.median(conf["rich"]) > 0.85, params.profile
        assert np.median(conf["uniform"]) < 0.5, params.profile


def test_centre_weighting_is_what_brings_the_matches_within_a_pixel(rendered_cases):
    def rate(params: CorrespondenceParams) -> float:
        errors = [np.hypot(m.x - truth[0], m.y - truth[1]) for pre, post, truth, kind in rendered_cases
                  if kind == "rich" for m in [match_eye(pre, post, params)]]
        return float(np.mean(np.array(errors) <= 1.0))

    # Without context and affine alignment (the search eqs. 1-6 make, as in the paper's profile).
    plain = CorrespondenceParams(context_levels=0)
    assert rate(plain) > rate(dataclasses.replace(plain, refine_sigma_fraction=0.0))


# --- repeated structure: where eqs. 4-7 are sure of a wrong match --------------------------
def row_of_books(true_book_seen: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """A row of five alike books, the fovea's one of them: the pre- and post-fixation images
    and where the fovea's patch centre was in the pre-fixation image (x). In the pre-fixation
    image the true book is a little blurred (the periphery of a fish-eye) while its
    neighbours are not; or, with `true_book_seen` False, hidden (the wall behind it): then
    every place a match can find is wrong."""
    rng = np.random.default_rng(7)
    pre = cv2.GaussianBlur((rng.random((H, W)) * 80 + 90).astype(np.float32), (0, 0), 3.0)
    wall = pre.copy()
    book = cv2.GaussianBlur(rng.random((22, 18), dtype=np.float32) * 220, (0, 0), 1.2) + 10
    truth = (150, 100)  # top-left of the true book
    for k in range(-2, 3):
        x0 = truth[0] + 24 * k
        pre[truth[1]:truth[1] + 22, x0:x0 + 18] = book if k else cv2.GaussianBlur(book, (0, 0), 0.9)
    # The head turned: the true book is now on the fovea (a pure shift of the pre image, crisp).
    dx, dy = (W - 18) // 2 - truth[0], (H - 22) // 2 - truth[1]
    post = np.roll(np.roll(pre, dy, axis=0), dx, axis=1)
    post[(H - 22) // 2:(H - 22) // 2 + 22, (W - 18) // 2:(W - 18) // 2 + 18] = book
    post = np.clip(post + rng.normal(0, 2.0, post.shape), 0, 255).astype(np.float32)
    if not true_book_seen:
        pre[truth[1]:truth[1] + 22, truth[0]:truth[0] + 18] = wall[truth[1]:truth[1] + 22, truth[0]:truth[0] + 18]
    return pre, post, truth[0] + 8.5


@pytest.mark.parametrize("true_book_seen", [True, False])
def test_a_repeat_fools_eqs_4_7_and_the_default_accepts_no_wrong_match(true_book_seen):
    """Eq. 1 prefers a crisp neighbour 24 px away; eq. 5 weighs that near competitor by its
    squared distance, so eqs. 4-7 accept it. The default finds the true book by its context
    and its larger refinement patch, or refuses (nearly equal context peaks, the backward
    check landing off the fovea); with the true book hidden, every match is wrong, and it
    refuses."""
    pre, post, true_x = row_of_books(true_book_seen)
    paper = match_eye(pre, post, PAPER)
    assert abs(paper.x - true_x) > 20, "eqs. 1-6 must pick a neighbouring book for this test to mean anything"
    assert paper.confidence >= 0.3, f"eqs. 4-7 accept it (c1 c2 = {paper.confidence:.2f})"
    default = match_eye(pre, post, CorrespondenceParams())
    right = true_book_seen and abs(default.x - true_x) <= 1.0
    assert right or default.confidence < 0.3, (default.x, default.confidence, default.second_peak,
                                               default.backward_px)
    if not true_book_seen:
        assert default.confidence < 0.3


def test_a_larger_backward_patch_sees_past_a_checkerboards_period():
    """A checkerboard of 14 px period with one mark 12 px beside the fovea: the foveal patch's
    size (20 x 20) holds only the board and lands on a repeat when searched back; 1.5 times
    it (30 x 30) holds the mark and lands on the fovea."""
    ys, xs = np.mgrid[0:600, 0:800]
    board = cv2.GaussianBlur((((xs // 7) + (ys // 7)) % 2 * 160 + 40).astype(np.float32), (0, 0), 1.0)
    board[150 + 117:150 + 123, 200 + 172:200 + 176] = 255.0
    rng = np.random.default_rng(3)
    post = view(board, 200, 150) + rng.normal(0, 2, (H, W)).astype(np.float32)
    pre = view(board, 150, 180) + rng.normal(0, 2, (H, W)).astype(np.float32)
    truth = ((W - 1) / 2 + 50, (H - 1) / 2 - 30)  # where the post-fixation fovea was in pre
    assert _backward_distance(pre, post, *truth, CorrespondenceParams()) > 5.0
    assert _backward_distance(pre, post, *truth, CorrespondenceParams(backward_patch_factor=1.5)) < 0.5
    with pytest.raises(ValueError, match="backward_patch_factor"):
        CorrespondenceParams(backward_patch_factor=0.5)


def beside_a_depth_edge(edge_px: int) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """A near surface left of an edge `edge_px` right of the fovea, a far one beyond it. The
    saccade moved the near surface's content by (30, 18) px and the far one's by (20, 15): the
    fovea's own patch moved with the near surface, most of its context did not."""
    near, far = texture(21, (300, 400)), texture(22, (300, 400))

    def image(near_shift: tuple[int, int], far_shift: tuple[int, int], edge_x: int) -> np.ndarray:
        out = far[30 - far_shift[1]:30 - far_shift[1] + H, 40 - far_shift[0]:40 - far_shift[0] + W].copy()
        out[:, :edge_x] = near[30 - near_shift[1]:30 - near_shift[1] + H, 40 - near_shift[0]:40 - near_shift[0] + W][:, :edge_x]
        return out

    post = image((0, 0), (0, 0), W // 2 + edge_px)
    pre = image((30, 18), (20, 15), W // 2 + edge_px + 30)
    return pre, post, ((W - 1) / 2 + 30, (H - 1) / 2 + 18)


@pytest.mark.parametrize("edge_px", [6, 8, 10])
def test_a_right_match_beside_a_depth_edge_teaches(edge_px):
    """The fovea's context moved otherwise than the fovea (parallax at a depth edge): the
    context peak correlates at only about 0.45. The match is right, distinct and passes the
    backward check, and both eyes alike would teach (c >= 0.3); with the context's tau of
    Table I's kind (0: c1 = 1/2 at a correlation of 0.5) the same fixation would be refused."""
    pre, post, truth = beside_a_depth_edge(edge_px)
    m = match_eye(pre, post, CorrespondenceParams())
    assert np.hypot(m.x - truth[0], m.y - truth[1]) <= 1.0
    assert m.context_c_max < 0.6 and m.backward_px < 1.5
    assert FixationMatch(m, m).confidence >= 0.3
    strict = match_eye(pre, post, CorrespondenceParams(context_min_correlation=0.0))
    assert FixationMatch(strict, strict).confidence < 0.3


@pytest.mark.parametrize("edge_px", [0, 2, 4])
def test_a_wrong_match_at_a_depth_edge_through_the_fovea_is_refused(edge_px):
    """The edge runs through the fovea's patch: half of it moved one way, half another, and
    no placement in the pre-fixation image is right; the backward check refuses what is found."""
    pre, post, truth = beside_a_depth_edge(edge_px)
    m = match_eye(pre, post, CorrespondenceParams())
    assert np.hypot(m.x - truth[0], m.y - truth[1]) > 3.0
    assert m.backward_px > 3.0 and m.confidence < 0.1


def test_the_default_confidence_is_high_on_a_plain_shift():
    tex = texture(8)
    pre, post = view(tex, 200, 150), view(tex, 160, 190)
    m = match_eye(pre, post, CorrespondenceParams())
    assert (m.x, m.y) == pytest.approx(((W - 1) / 2 - 40, (H - 1) / 2 + 40), abs=0.3)
    assert m.confidence > 0.9 and m.backward_px < 0.5 and m.second_peak < m.context_c_max - 0.2
    assert FixationMatch(m, m).confidence == pytest.approx(m.confidence ** 2)  # eq. 7: the product


def test_profiles():
    assert PAPER.paper and not CorrespondenceParams().paper
    with pytest.raises(ValueError, match="profile"):
        CorrespondenceParams(profile="best")


# --- the photo room (issue 14's goal, on fewer pairs than benchmarks/bench/fixation.py) ----
@pytest.fixture(scope="module")
def photo_room_cases():
    model = HeadModel.default(limits=JointLimits(vergence=(1.0, 20.0)))
    return saccade_cases(shared_scene(0, False, "photos"), model, 120, seed=5)


def test_photo_room_correspondence_meets_the_goal_and_beats_eqs_4_7(photo_room_cases):
    default = accuracy(list(scored(photo_room_cases, CorrespondenceParams())))
    paper = accuracy(list(scored(photo_room_cases, PAPER)))
    assert default.cases >= 200
    assert default.within_1px >= 0.97, default.line()
    assert default.wrong_accepted <= 0.01, default.line()
    assert default.right_accepted >= 0.85, default.line()
    assert paper.within_1px < default.within_1px, paper.line()
    # The alignment is what takes the fish-eye periphery's last pixel of bias away.
    translation_only = accuracy(list(scored(photo_room_cases, CorrespondenceParams(alignment_iterations=0))))
    assert translation_only.within_1px < default.within_1px, translation_only.line()
