#!/usr/bin/env python3
"""How good are the optical-flow targets on the movers of a generated video?

usage: mover_flow.py SCENE RUN [SCENE RUN ...]

SCENE is a `nerf synth --preset family` folder (its gt/train holds the exact forward flow and
depth), RUN an `nsff train` run directory whose flow_cache/ holds the built-in flow. A pixel is
a mover pixel when its exact flow differs by more than 0.3 px from the flow the camera alone
would give its exact depth (the generator's camera depth along −z; 0 where no surface is hit).
Prints, per scene, the built-in flow's end-point error on mover and static pixels, the
movers' own motion (exact flow minus the camera's) and the share of mover pixels that the
flow's forward-backward consistency mask keeps (only those train the projected-flow term).
"""
import json
import math
import sys

import numpy as np


def camera_flow(depth, c2w, c2w_next, focal, width, height):
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    # Camera rays with z = -1, so a point is the ray times its camera depth.
    dirs = np.stack([(j - width / 2) / focal, -(i - height / 2) / focal, -np.ones_like(j)], -1)
    world = (dirs * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]
    w2c = np.linalg.inv(c2w_next)
    q = world @ w2c[:3, :3].T + w2c[:3, 3]
    u = width / 2 + focal * q[..., 0] / -q[..., 2]
    v = height / 2 - focal * q[..., 1] / -q[..., 2]
    return np.stack([u - j, v - i], -1)


def scene_stats(scene, run):
    meta = json.load(open(f"{scene}/transforms_train.json"))
    frames = meta["frames"]
    rows = []
    for k in range(len(frames) - 1):
        exact = np.load(f"{scene}/gt/train/r_{k:03d}_flow_fwd.npy")
        depth = np.load(f"{scene}/gt/train/r_{k:03d}_depth.npy")
        height, width = exact.shape[:2]
        focal = 0.5 * width / math.tan(0.5 * meta["camera_angle_x"])
        c2w = np.array(frames[k]["transform_matrix"])
        c2w_next = np.array(frames[k + 1]["transform_matrix"])
        surface = depth > 0
        own = np.linalg.norm(exact - camera_flow(depth, c2w, c2w_next, focal, width, height), axis=-1)
        mover = surface & (own > 0.3)
        if not mover.any():
            continue
        cache = np.load(f"{run}/flow_cache/{k:05d}_fwd.npz")
        err = np.linalg.norm(cache["flow"] - exact, axis=-1)
        rows.append((err[mover].mean(), err[surface & ~mover].mean(), np.median(own[mover]),
                     cache["mask"][mover].mean(), mover.sum()))
    if not rows:
        sys.exit(f"{scene}: no mover pixels in any training frame")
    return np.array(rows).mean(axis=0)


def main(args):
    if len(args) < 2 or len(args) % 2:
        sys.exit(__doc__)
    print("scene | EPE on movers (px) | EPE static (px) | movers' own motion (median px) | mask keeps | mover px/frame")
    for scene, run in zip(args[::2], args[1::2]):
        m, s, own, kept, n = scene_stats(scene, run)
        print(f"{scene} | {m:.2f} | {s:.2f} | {own:.2f} | {kept:.2f} | {n:.0f}")


if __name__ == "__main__":
    main(sys.argv[1:])
