#!/usr/bin/python3
"""Whole-scene reconstructions of a simulated pair by Open3D, to check planesdf on another mapper's output.

Fuses each session's TUM folder of a `planesdf simulate` folder with Open3D and writes, beside
the simulator's own `*_recon.ply`:
  {reference,current}_o3d{V}_pts.ply   tensor VoxelBlockGrid, extract_point_cloud (points and
                                       normals, weight >= 3), voxel V mm, truncation 4 voxels
  {reference,current}_o3d{V}_mesh.ply  legacy ScalableTSDFVolume, extract_triangle_mesh
                                       (vertices, normals, faces; with --mesh)
The frames are the simulator's reported poses (its localisation error included), as a mapper
exports them. Score with the simulator's ground truth of its reconstructions:
  planesdf detect DIR/reference_o3d10_pts.ply DIR/current_o3d10_pts.ply --out D
  planesdf eval D --gt-reference DIR/gt/reference_recon.ply \\
                  --gt-current DIR/gt/current_recon.ply --tol 0.01

Needs Debian's python3-open3d (run with /usr/bin/python3). Usage:
  bench/open3d_recon.py SIM_DIR [--voxel-mm 10] [--mesh]
"""
import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from open3d_peer import DEPTH_MAX, TRUNC_VOXELS, fuse_frames, read_tum  # noqa: E402


def fuse_points(folder, voxel):
    """Open3D's tensor VoxelBlockGrid of the frames, as a point cloud with normals."""
    vbg = fuse_frames(folder, voxel, 400000)
    return vbg.extract_point_cloud(weight_threshold=3.0, estimated_point_number=8000000)


def fuse_mesh(folder, voxel):
    """Open3D's legacy ScalableTSDFVolume of the frames, as a triangle mesh with normals (the
    tensor grid's mesh extraction aborts on some rooms in Open3D 0.16)."""
    import numpy as np
    import open3d as o3d

    k, frames = read_tum(folder)
    volume = o3d.pipelines.integration.ScalableTSDFVolume(
        voxel_length=voxel, sdf_trunc=TRUNC_VOXELS * voxel,
        color_type=o3d.pipelines.integration.TSDFVolumeColorType.NoColor)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(int(k["width"]), int(k["height"]), k["fx"],
                                                  k["fy"], k["cx"], k["cy"])
    scale = k.get("depth_scale", 5000.0)
    for path, extrinsic in frames:
        depth = o3d.io.read_image(path)
        grey = o3d.geometry.Image(np.zeros(np.asarray(depth).shape + (3,), np.uint8))
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            grey, depth, depth_scale=scale, depth_trunc=DEPTH_MAX,
            convert_rgb_to_intensity=False)
        volume.integrate(rgbd, intrinsic, extrinsic)
    mesh = volume.extract_triangle_mesh()
    mesh.compute_vertex_normals()
    return mesh


def write_atomically(path, write):
    tmp = path + ".tmp.ply"
    if not write(tmp):
        sys.exit(f"open3d_recon: could not write {path}")
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sim", help="a `planesdf simulate` output folder")
    ap.add_argument("--voxel-mm", type=float, default=10.0)
    ap.add_argument("--mesh", action="store_true", help="also the legacy volume's mesh")
    args = ap.parse_args()
    import open3d as o3d

    voxel = args.voxel_mm / 1000.0
    tag = f"o3d{args.voxel_mm:g}"
    for session in ("reference", "current"):
        folder = os.path.join(args.sim, session)
        if not os.path.isfile(os.path.join(folder, "groundtruth.txt")):
            sys.exit(f"open3d_recon: {folder}: no TUM folder (groundtruth.txt missing)")
        points = fuse_points(folder, voxel)
        out = os.path.join(args.sim, f"{session}_{tag}_pts.ply")
        write_atomically(out, lambda p: o3d.t.io.write_point_cloud(p, points))
        print(f"{out}: {points.point.positions.shape[0]} points", file=sys.stderr)
        if args.mesh:
            mesh = fuse_mesh(folder, voxel)
            out = os.path.join(args.sim, f"{session}_{tag}_mesh.ply")
            write_atomically(out, lambda p: o3d.io.write_triangle_mesh(p, mesh))
            print(f"{out}: {len(mesh.vertices)} vertices", file=sys.stderr)


if __name__ == "__main__":
    main()
