#!/usr/bin/python3
"""planesdf against Open3D on the same depth frames, side by side in one run (issue 28).

Fuses the frames of a TUM folder (default: `planesdf simulate --scene tabletop --seed 7`, the
reference session of `planesdf bench`) with `planesdf fuse` (plane bands only) and with Open3D's
tensor VoxelBlockGrid on the CPU (the whole scene), at the same voxel size, truncation (4 voxels)
and depth range, alternating the two `--rounds` times. Reports each one's median time per frame
(frame loading not included) and the ratio planesdf / Open3D.

Needs Debian's python3-open3d (run with /usr/bin/python3). Usage:
  bench/open3d_peer.py [--planesdf build/bin/planesdf] [--tum DIR] [--rounds 3] [--json FILE]
"""
import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

VOXEL = 0.007  # Config::voxel_size
TRUNC_VOXELS = 4.0  # Config::truncation_voxels
DEPTH_MAX = 4.0  # Config::max_depth


def read_tum(folder):
    """(intrinsics dict, [(depth path, 4x4 world-to-camera)]) of a planesdf TUM folder."""
    import numpy as np

    k = {}
    with open(os.path.join(folder, "intrinsics.txt")) as f:
        for line in f:
            parts = line.split()
            if len(parts) == 2 and not line.startswith("#"):
                k[parts[0]] = float(parts[1])
    poses = {}
    with open(os.path.join(folder, "groundtruth.txt")) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            t, tx, ty, tz, qx, qy, qz, qw = map(float, line.split())
            r = np.array([
                [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = r, (tx, ty, tz)
            poses[round(t, 6)] = np.linalg.inv(pose)
    frames = []
    with open(os.path.join(folder, "depth.txt")) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            t, name = line.split()
            if round(float(t), 6) in poses:
                frames.append((os.path.join(folder, name), poses[round(float(t), 6)]))
    return k, frames


def fuse_frames(folder, voxel, block_count, timed=None):
    """Open3D's tensor VoxelBlockGrid (CPU) of the frames of a TUM folder, whole scene; appends
    each frame's integration time (ms, frame loading not included) to `timed` when given."""
    import open3d as o3d
    import open3d.core as o3c

    k, frames = read_tum(folder)
    device = o3c.Device("CPU:0")
    intrinsic = o3c.Tensor([[k["fx"], 0, k["cx"]], [0, k["fy"], k["cy"]], [0, 0, 1]],
                           o3c.Dtype.Float64)
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight"), attr_dtypes=(o3c.float32, o3c.float32),
        attr_channels=((1), (1)), voxel_size=voxel, block_resolution=8,
        block_count=block_count, device=device)
    scale = k.get("depth_scale", 5000.0)
    for path, extrinsic in frames:
        depth = o3d.t.io.read_image(path).to(device)
        ext = o3c.Tensor(extrinsic, o3c.Dtype.Float64)
        t0 = time.perf_counter()
        blocks = vbg.compute_unique_block_coordinates(depth, intrinsic, ext, scale, DEPTH_MAX,
                                                      TRUNC_VOXELS)
        vbg.integrate(blocks, depth, intrinsic, ext, scale, DEPTH_MAX, TRUNC_VOXELS)
        if timed is not None:
            timed.append((time.perf_counter() - t0) * 1000.0)
    return vbg


def open3d_ms(folder):
    """Median ms per frame of Open3D's VoxelBlockGrid integration of the whole scene."""
    times = []
    fuse_frames(folder, VOXEL, 100000, times)
    return statistics.median(times), len(times)


def planesdf_ms(binary, folder):
    """`planesdf fuse`'s reported Map::integrate median (ms per frame)."""
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([binary, "fuse", folder, "--out", os.path.join(tmp, "map.psdf")],
                           capture_output=True, text=True, check=True)
    m = re.search(r"Map::integrate median ([0-9.]+) ms/frame", r.stderr)
    if not m:
        sys.exit("open3d_peer: no 'Map::integrate median' line from " + binary)
    return float(m.group(1))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--planesdf", default="build/bin/planesdf")
    ap.add_argument("--tum", help="a TUM folder (default: simulate tabletop seed 7)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.tum
        if not folder:
            subprocess.run([args.planesdf, "simulate", "--scene", "tabletop", "--seed", "7",
                            "--out", os.path.join(tmp, "sim")], capture_output=True, check=True)
            folder = os.path.join(tmp, "sim", "reference")
        ours, theirs, frames = [], [], 0
        for r in range(args.rounds):
            ours.append(planesdf_ms(args.planesdf, folder))
            ms, frames = open3d_ms(folder)
            theirs.append(ms)
            print(f"round {r + 1}/{args.rounds}: planesdf {ours[-1]:.1f} ms, "
                  f"Open3D {theirs[-1]:.1f} ms per frame (medians)", file=sys.stderr)
    out = {"frames": frames, "voxel_size": VOXEL, "truncation_voxels": TRUNC_VOXELS,
           "planesdf_integrate_ms_median": statistics.median(ours),
           "open3d_integrate_ms_median": statistics.median(theirs),
           "planesdf_rounds": ours, "open3d_rounds": theirs}
    out["ratio"] = out["planesdf_integrate_ms_median"] / out["open3d_integrate_ms_median"]
    print(f"planesdf {out['planesdf_integrate_ms_median']:.1f} ms, Open3D VoxelBlockGrid (whole "
          f"scene) {out['open3d_integrate_ms_median']:.1f} ms per frame: ratio "
          f"{out['ratio']:.2f} (target <= 0.5)")
    if args.json:
        with open(args.json + ".tmp", "w") as f:
            json.dump(out, f, indent=2)
        os.replace(args.json + ".tmp", args.json)


if __name__ == "__main__":
    main()
