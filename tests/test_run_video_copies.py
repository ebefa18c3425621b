"""How often `--output-video` writes each processed frame: in the frames' own time, but
bounded, whatever the source's frame rate or a stall."""

from follow.run import MAX_VIDEO_COPIES, Outputs


def test_the_copies_of_one_frame_are_bounded_whatever_the_frame_rate():
    # A source claiming 10^6 fps, its frames 1/15 s apart: 66,667 copies each (a --realtime
    # run with --output-video crawled, then died with SIGABRT).
    outputs = Outputs({}, 1_000_000.0)
    copies = [outputs._video_copies(i / 15) for i in range(4)]
    assert copies[0] == 1 and max(copies) == MAX_VIDEO_COPIES == 480


def test_a_stall_is_shown_short_and_not_spilled_onto_the_frames_after_it():
    outputs = Outputs({}, 30.0)
    stamps_s = [0.0, 1 / 30, 10.0] + [10.0 + i / 30 for i in range(1, 6)]
    copies = [outputs._video_copies(s) for s in stamps_s]
    assert copies == [1, 1, 60, 1, 1, 1, 1, 1]  # 2 s of the 10 s stall, then on time
