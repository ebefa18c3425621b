"""`follow eval pose-scene`: the people-sized input against one fixed input height, on
the robot scene (follow/eval/robot_scene.py: real person crops where a 60-degree camera
1 m up sees people at their distances, walking side to side).

Per person, the share of frames whose neck the detector finds in the upper 40 % of the
person and whose ankle it also finds in the lower quarter (as `follow eval pose-near`
counts them), the share of frames run at each input height, and the network's mean
time a frame. People covered by nearer ones count as missed alike in both settings, so
the rates compare the settings rather than measure the detector.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from follow.cli_args import positive_int

DEFAULT_SCENES = "1:5,3:4,5:5,5:8"


def scene_list(text: str) -> list[tuple[int, float]]:
    """`1:5,5:8`: (people, farthest distance in metres) pairs."""
    import argparse

    try:
        pairs = [item.split(":") for item in text.split(",") if item.strip()]
        scenes = [(int(people), float(far)) for people, far in pairs]
    except ValueError:
        scenes = []
    if not scenes:
        raise argparse.ArgumentTypeError(f"'{text}': give PEOPLE:FAR_M pairs, e.g. 1:5,5:8")
    from follow.eval.robot_scene import MAX_FAR_M, MAX_PEOPLE, MIN_FAR_M

    for people, far in scenes:  # every scene checked before the first one runs
        if not (1 <= people <= MAX_PEOPLE and MIN_FAR_M <= far <= MAX_FAR_M):
            raise argparse.ArgumentTypeError(
                f"'{people}:{far:g}': a scene holds 1-{MAX_PEOPLE} people, the farthest "
                f"{MIN_FAR_M:g}-{MAX_FAR_M:g} m away"
            )
    return scenes


def add_arguments(p) -> None:
    p.add_argument("--scenes", type=scene_list, default=scene_list(DEFAULT_SCENES),
                   help="robot scenes as PEOPLE:FAR_M pairs (1-5 people, the farthest 3-15 m "
                        f"away; default {DEFAULT_SCENES})")  # fmt: skip
    p.add_argument("--frames", type=positive_int, default=90, help="frames per scene (default 90)")
    p.add_argument("--config", help="TOML configuration over the robot defaults")


def person_rates(detector, scene, frames: int) -> dict:
    """Per person: neck and ankle found shares; input height shares; mean network ms."""
    from tqdm import tqdm

    from follow.eval.pose_near import ankle_found, observations_on_person
    from follow.eval.robot_scene import FRAME_SIZE
    from follow.pose.observations import skeletons_to_observations

    people = len(scene.distances_m)
    necks, ankles = np.zeros(people), np.zeros(people)
    heights, inference_ms = [], []
    for index in tqdm(range(frames), desc="pose-scene", unit="frame", leave=False):
        skeletons = detector.detect(scene.read_frame(index))
        heights.append(detector.last_input_height_px)
        inference_ms.append(detector.last_timing_ms["inference"])
        observations = skeletons_to_observations(skeletons, FRAME_SIZE, detector.config)
        for person in range(people):
            box = scene.person_box_px(person, index)
            on_person = observations_on_person(observations, box)
            necks[person] += bool(on_person)
            ankles[person] += ankle_found(on_person, box)
    return {
        "neck": np.round(necks / frames, 3).tolist(),
        "ankle": np.round(ankles / frames, 3).tolist(),
        "input_height_px_shares": {int(h): round(heights.count(h) / frames, 3)
                                   for h in sorted(set(heights))},  # fmt: skip
        "inference_ms_mean": round(float(np.mean(inference_ms)), 2),
    }


def main(args) -> dict:
    from follow.config import Config
    from follow.eval.robot_scene import RobotScene
    from follow.eval.verification import data_root
    from follow.pose.detector import PoseDetector

    config = Config.load(args.config) if args.config else Config()
    settings = {"people-sized": dataclasses.replace(config.pose, input_height_from_people=True),
                "fixed": dataclasses.replace(config.pose, input_height_from_people=False)}  # fmt: skip
    detectors = {name: PoseDetector(pose) for name, pose in settings.items()}
    rows = []
    for people, far_m in args.scenes:
        scene = RobotScene(data_root(None, has_option=False), people, far_m, args.frames)
        row = {"people": people, "far_m": far_m, "distances_m": scene.distances_m}
        for name, detector in detectors.items():
            detector.reset_input_sizing()
            row[name] = person_rates(detector, scene, args.frames)
        row["inference_ratio"] = round(row["people-sized"]["inference_ms_mean"]
                                       / row["fixed"]["inference_ms_mean"], 3)  # fmt: skip
        rows.append(row)
    if not args.json:
        print(f"robot scene, {args.frames} frames each, input {config.pose.input_height_px} px "
              "fixed against people-sized")  # fmt: skip
        for row in rows:
            print(f"{row['people']} people, {', '.join(f'{d:.1f}' for d in row['distances_m'])} m:"
                  f" network time people-sized / fixed {row['inference_ratio']:.2f}")  # fmt: skip
            for name in settings:
                r = row[name]
                shares = ", ".join(f"{h} px {s:.0%}" for h, s in r["input_height_px_shares"].items())
                print(f"  {name:12s} neck {r['neck']} ankle {r['ankle']} ({shares}; "
                      f"{r['inference_ms_mean']} ms)")  # fmt: skip
    return {"frames": args.frames, "input_height_px": config.pose.input_height_px, "rows": rows}
