"""Clips: the exported frames are the player's frames; bad requests are clear errors."""

import numpy as np
import pytest

from engine.export import Clip, ClipError, MAX_FRAMES, parse_track, play_clip
from engine.player import Player


def test_frames_cover_both_ends_of_the_clip(export_spaces):
    frames = play_clip(export_spaces["speed"], Clip(duration=1.0, rate=30))
    assert len(frames) == 31 and frames.times[0] == 0 and frames.times[-1] == pytest.approx(1.0)
    assert frames.local.shape == (31, export_spaces["speed"].n_vertices, 3) and frames.local.dtype == np.float32
    assert np.all(frames.root_position[0] == 0) and frames.heading[0] == 0


def test_frames_are_what_the_player_plays(export_spaces):
    """Frame k is the player after k steps of 1 / rate, with the track's requests at their times
    (what a stream at that rate shows): the same root and parameters, the same vertices to float32
    rounding (the blender's phase tables, filled as weights recur, round the last bit differently)."""
    space = export_spaces["speed"]
    clip = Clip(params={"speed": 1.2}, track=((0.5, {"speed": 2.4}),), duration=1.5, rate=20, smoothing=0.3)
    frames = play_clip(space, clip)
    player = Player(space, smoothing=0.3, params={"speed": 1.2})
    for k in range(len(frames)):
        if k == 10:  # t = 0.5 s
            player.set_params({"speed": 2.4})
        frame = player.step(0.05) if k else player.frame()
        np.testing.assert_allclose(frames.world(k), frame.vertices, rtol=0, atol=1e-6, err_msg=str(k))
        assert np.array_equal(frames.root_position[k], frame.root_position) and frames.heading[k] == frame.heading
        assert np.array_equal(frames.params[k], frame.realised)
    assert frames.params[-1][0] > 2.0 > frames.params[5][0]  # the request took effect
    assert frames.root_position[-1][2] > 1.0  # it walked forward (+Z)


def test_a_one_shot_clip_holds_its_last_frame(export_spaces):
    frames = play_clip(export_spaces["jump"], Clip(duration=3.0, rate=15))
    assert np.array_equal(frames.local[-1], frames.local[-2])  # finished: held


@pytest.mark.parametrize("clip, message", [
    (Clip(params={"sped": 1.0}), "unknown parameter 'sped'; speed has speed"),
    (Clip(params={"speed": 9.0}), "params: speed = 9 m/s is out of range; speed spans"),
    (Clip(params={"speed": float("nan")}), "speed must be a finite number"),
    (Clip(params={"speed": "fast"}), "speed must be a finite number, got 'fast'"),
    (Clip(track=((2.0, {"speed": 0.1}),)), "track at 2 s: speed = 0.1 m/s is out of range"),
    (Clip(track=((11.0, {"speed": 1.0}),)), "track: time 11.0 is outside the clip [0, 10] s"),
    (Clip(duration=0), "duration must be a positive number of seconds"),
    (Clip(rate=-1), "rate must be a positive number"),
    (Clip(mode="cubic"), "unknown blend mode 'cubic'"),
    (Clip(smoothing=-1), "smoothing must be a non-negative"),
    (Clip(duration=MAX_FRAMES, rate=60), f"at most {MAX_FRAMES} per clip"),
])
def test_bad_clips_are_clear_errors(export_spaces, clip, message):
    with pytest.raises(ClipError) as error:
        play_clip(export_spaces["speed"], clip)
    assert message in str(error.value)


def test_tracks_parse_from_json_documents():
    params, track = parse_track({"params": {"speed": 1.0}, "track": [{"time": 2, "params": {"speed": 2.0}}]})
    assert params == {"speed": 1.0} and track == [(2.0, {"speed": 2.0})]
    assert parse_track({}) == ({}, [])
    for document, message in (([], "expected a JSON object"), ({"speed": 1}, "unknown key(s) speed"),
                              ({"track": [{"time": "2", "params": {}}]}, "track[0] must be"),
                              ({"track": {"time": 1}}, "track must be a list"), ({"params": [1]}, "params must be")):
        with pytest.raises(ClipError, match="track.json") as error:
            parse_track(document, "track.json")
        assert message in str(error.value)
