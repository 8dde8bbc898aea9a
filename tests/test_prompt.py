"""Masks from clicks and boxes: on a photo and along a video."""

import cv2
import numpy as np
import pytest

from marionette.errors import InputError
from marionette.segment.prompt import Prompt, prompted_mask
from marionette.source.prompted import prompted_masks

H, W = 120, 160


def two_objects(shift=0):
    """(H, W, 3) image: a red disc (left) and a blue square (right) on a grey, lightly textured ground, and
    their masks; ``shift`` moves both right by that many pixels."""
    rng = np.random.default_rng(0)
    image = (120 + rng.normal(0, 6, (H, W, 3))).clip(0, 255).astype(np.uint8)
    yy, xx = np.mgrid[:H, :W]
    disc = (xx - 45 - shift) ** 2 + (yy - 60) ** 2 < 25**2
    square = (np.abs(xx - 115 - shift) < 22) & (np.abs(yy - 60) < 22)
    image[disc] = (210, 40, 30)
    image[square] = (30, 60, 200)
    return image, disc, square


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_a_click_picks_the_object_under_it():
    image, disc, square = two_objects()
    assert iou(prompted_mask(image, Prompt(points=((45, 60),))), disc) > 0.9
    assert iou(prompted_mask(image, Prompt(points=((115, 60),))), square) > 0.9


def test_a_box_picks_the_object_in_it():
    image, disc, square = two_objects()
    assert iou(prompted_mask(image, Prompt(box=(88, 33, 142, 88))), square) > 0.9


def test_an_excluded_point_takes_out_what_the_box_took_in_wrongly():
    image, disc, square = two_objects()
    both = Prompt(box=(15, 30, 142, 90))
    taken = prompted_mask(image, both)
    assert taken[disc].mean() > 0.8 and taken[square].mean() > 0.8
    fixed = prompted_mask(image, Prompt(box=both.box, exclude=((115, 60),)))
    assert iou(fixed, disc) > 0.9


def touching_objects(shift=0, half=22):
    """(H, W, 3) image: a red disc and a blue square (``half`` its half side) that overlap (one salient region),
    and their masks; ``shift`` moves both right by that many pixels."""
    rng = np.random.default_rng(0)
    image = (120 + rng.normal(0, 6, (H, W, 3))).clip(0, 255).astype(np.uint8)
    yy, xx = np.mgrid[:H, :W]
    disc = (xx - 55 - shift) ** 2 + (yy - 60) ** 2 < 25**2
    square = (np.abs(xx - 78 - half - shift) < half) & (np.abs(yy - 60) < half) & ~disc
    image[disc] = (210, 40, 30)
    image[square] = (30, 60, 200)
    return image, disc, square


def test_an_excluded_point_splits_off_what_touches_the_clicked_object():
    """A bag and the hand holding it: one salient region, which a click keeps whole; a point excluded on
    the other thing splits it at their boundary."""
    image, disc, square = touching_objects()
    whole = prompted_mask(image, Prompt(points=((50, 60),)))
    assert whole[disc].mean() > 0.9 and whole[square].mean() > 0.9
    assert iou(prompted_mask(image, Prompt(points=((50, 60),), exclude=((105, 60),))), disc) > 0.95
    assert iou(prompted_mask(image, Prompt(points=((105, 60),), exclude=((50, 60),))), square) > 0.95


def test_what_an_excluded_point_splits_off_stays_out_along_the_video():
    """The automatic masks take both moving things as one (and would agree with the disc followed alone):
    the square, excluded on frame 0, stays out of every frame."""
    frames, discs = zip(*[touching_objects(shift=2 * t, half=15)[:2] for t in range(6)])
    masks = prompted_masks(np.stack(frames), Prompt(points=((50, 60),), exclude=((95, 60),)))
    assert min(iou(m, d) for m, d in zip(masks, discs)) > 0.9


@pytest.mark.parametrize("prompt, message", [
    (Prompt(points=((200, 10),)), "outside the 160x120"),
    (Prompt(box=(10, 10, 10, 50)), "has no area"),
    (Prompt(box=(500, 500, 600, 600)), "outside"),
    (Prompt(exclude=((10, 10),)), "need a point or a box"),
])
def test_bad_prompts_are_refused(prompt, message):
    image, _, _ = two_objects()
    with pytest.raises(InputError, match=message):
        prompted_mask(image, prompt)


def test_a_prompt_on_a_blank_image_selects_nothing():
    with pytest.raises(InputError, match="selects nothing|no object"):
        prompted_mask(np.full((H, W, 3), 128, np.uint8), Prompt(box=(20, 20, 60, 60)))


def test_a_clicked_object_is_followed_through_a_video():
    """The blue square, clicked on frame 0, as both objects slide right: the masks follow the square."""
    frames, truths = [], []
    for t in range(6):
        image, _, square = two_objects(shift=3 * t)
        frames.append(image)
        truths.append(square)
    masks = prompted_masks(np.stack(frames), Prompt(points=((115, 60),)))
    assert masks.shape == (6, H, W)
    assert min(iou(m, s) for m, s in zip(masks, truths)) > 0.85


def test_a_prompt_scaled_with_its_image_keeps_pixel_centres():
    prompt = Prompt(points=((0.0, 9.0),), box=(1.0, 1.0, 9.0, 9.0), exclude=((5.0, 5.0),))
    half = prompt.scaled(0.5)
    assert half.points == ((-0.25, 4.25),)
    assert half.box == (0.25, 0.25, 4.25, 4.25)
    assert cv2 is not None


def write_clip(folder, frames):
    from marionette.io import write_video

    write_video(folder, frames, 10.0)
    return folder


def sliding_clip(tmp_path):
    frames = np.stack([two_objects(shift=3 * t)[0] for t in range(6)])
    return write_clip(tmp_path / "frames", frames)


def test_the_command_line_follows_the_clicked_object_and_saves_its_masks(tmp_path):
    from marionette.cli import main
    from marionette.io import read_masks

    clip = sliding_clip(tmp_path)
    out = tmp_path / "masks"
    assert main(["extract", str(clip), "-o", str(tmp_path / "p.npz"), "--source-point", "115,60",
                 "--save-masks", str(out), "-q"]) == 0
    assert (tmp_path / "p.npz").exists()
    masks = read_masks(out, count=6, size=(W, H))  # the layout --masks reads
    truth = [two_objects(shift=3 * t)[2] for t in range(6)]
    assert min(iou(m, s) for m, s in zip(masks, truth)) > 0.85
    # The saved masks can be given back as they are.
    assert main(["extract", str(clip), "-o", str(tmp_path / "q.npz"), "--masks", str(out), "-q"]) == 0


def test_the_command_line_picks_the_clicked_target(tmp_path, prior_file):
    from marionette.cli import main
    from marionette.io import read_video

    image, _, _ = two_objects()
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    for point, colour in (("45,60", (210, 40, 30)), ("115,60", (30, 60, 200))):
        out = tmp_path / f"out{point}"
        assert main(["transfer", str(prior_file), str(photo), "-o", str(out), "--target-point", point, "-q"]) == 0
        first = read_video(out).frames[0].reshape(-1, 3).astype(int)
        shown = first[np.abs(first - 255).sum(axis=1) > 60]  # not the white background
        assert len(shown) > 500
        assert np.abs(np.median(shown, axis=0) - colour).max() < 40  # the clicked object, alone


@pytest.mark.parametrize("args, message", [
    (["--source-point", "900,10"], "outside the 160x120 first frame"),
    (["--source-box", "5,5,5,50"], "has no area"),
    (["--source-point", "1,2,3"], "--source-point must be X,Y"),
    (["--source-exclude", "10,10"], "--source-exclude needs a --source-point or --source-box"),
    (["--source-point", "115,60", "--masks", "MASKS"], "mask folder or as a prompt, not both"),
    (["--save-masks", "FILE"], "is a file, not a folder"),
])
def test_the_command_line_refuses_bad_source_prompts(tmp_path, capsys, args, message):
    from marionette.cli import main

    clip = sliding_clip(tmp_path)
    (tmp_path / "FILE").write_text("mine")
    (tmp_path / "MASKS").mkdir()
    args = [str(tmp_path / a) if a in ("FILE", "MASKS") else a for a in args]
    out = tmp_path / "p.npz"
    assert main(["extract", str(clip), "-o", str(out), *args, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists() and (tmp_path / "FILE").read_text() == "mine"


@pytest.mark.parametrize("args, message", [
    (["--target-point", "500,10"], "outside the 160x120 target image"),
    (["--target-box", "10,10,50,10"], "has no area"),
])
def test_the_command_line_refuses_bad_target_prompts(tmp_path, prior_file, capsys, args, message):
    from marionette.cli import main

    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), two_objects()[0])
    out = tmp_path / "out.mp4"
    assert main(["transfer", str(prior_file), str(photo), "-o", str(out), *args, "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and message in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("motion, seed", [("inplane", 0), ("oscillation", 1)])
def test_a_click_on_a_turning_box_keeps_all_of_it(motion, seed):
    """The faces of one box move by different homographies, but they meet at its creases: not two objects."""
    from marionette.synthetic import make_scene

    scene = make_scene(motion, seed=seed, num_frames=6, size=(W, H))
    depth = cv2.distanceTransform(scene.masks[0].astype(np.uint8), cv2.DIST_L2, 5)
    y, x = np.unravel_index(np.argmax(depth), depth.shape)
    masks = prompted_masks(scene.frames, Prompt(points=((float(x), float(y)),)))
    assert iou(masks[0], scene.masks[0]) > 0.9


def touching_squares(t):
    """Frame ``t`` (H, W) grey of two textured squares side by side, the left one sliding down and the right one
    up by 2 px a frame, and their masks."""
    rng = np.random.default_rng(1)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (60, 60)).astype(np.float32), (0, 0), 1.5)
    grey = np.full((H, W), 128.0, np.float32)
    left, right = np.zeros((H, W), bool), np.zeros((H, W), bool)
    grey[25 + 2 * t:85 + 2 * t, 20:80] = texture
    left[25 + 2 * t:85 + 2 * t, 20:80] = True
    grey[35 - 2 * t:95 - 2 * t, 80:140] = texture[::-1]
    right[35 - 2 * t:95 - 2 * t, 80:140] = True
    return grey.astype(np.uint8), left, right


def test_a_click_takes_one_of_two_touching_objects_that_move_apart():
    from marionette.source.prompted import _moving_with

    grey = np.stack([touching_squares(t)[0] for t in range(5)])
    _, left, right = touching_squares(0)
    both = left | right
    assert iou(_moving_with(both, ((50.0, 55.0),), grey), left) > 0.85
    assert iou(_moving_with(both, ((110.0, 65.0),), grey), right) > 0.85
    assert _moving_with(left, ((50.0, 55.0),), grey).sum() == left.sum()  # one object alone stays whole


def test_a_followed_mask_does_not_spill_past_an_automatic_mask_that_holds_it():
    """The automatic mask takes the object with what holds it (so the two disagree); the carried mask, snapped to
    the frame's edges, would spill onto a background of the object's colour, and stays within a reach of it."""
    from marionette.source.prompted import _follow

    rng = np.random.default_rng(1)
    image = (110 + rng.normal(0, 5, (80, 120, 3))).clip(0, 255).astype(np.uint8)
    thing = np.zeros((80, 120), bool)
    thing[20:60, 50:90] = True
    holder = np.zeros_like(thing)
    holder[15:65, 10:50] = True
    alike = np.zeros_like(thing)  # background of the thing's colour, which the previous frame took in
    alike[20:60, 90:98] = True
    image[thing | alike] = (60, 90, 200)
    image[holder] = (20, 20, 20)
    reach = 4
    followed = _follow(thing | alike, image, thing | holder, (120, 80), reach)
    assert followed[thing].all()
    assert not followed[:, 90 + reach + 1:].any()


def test_a_point_excluded_on_the_background_does_not_cut_the_object_that_later_covers_it():
    """What an excluded point puts out is carried along the flow: where the object moves over it, the object's
    own pixels carry on instead, and the background point leaves no hole."""
    from marionette.synthetic import make_scene

    scene = make_scene("translation", num_frames=16, size=(W, H), seed=0)
    later = scene.masks[-1] & ~scene.masks[0]
    ys, xs = np.nonzero(later)
    point = (float(xs[len(xs) // 2]), float(ys[len(ys) // 2]))  # background on frame 0, the object's at the end
    depth = cv2.distanceTransform(scene.masks[0].astype(np.uint8), cv2.DIST_L2, 5)
    y, x = np.unravel_index(np.argmax(depth), depth.shape)
    masks = prompted_masks(scene.frames, Prompt(points=((float(x), float(y)),), exclude=(point,)))
    assert masks[-1][round(point[1]), round(point[0])]
    assert min(iou(m, s) for m, s in zip(masks, scene.masks)) > 0.9
