"""Benchmark of the sensor simulator: N frames at 1032x772 with LiDAR on the demo building.

Target (issue 4): 200 frames with LiDAR in under 60 s on a 2-core machine. Prints the wall time of
each stage and the CPU time summed over the render workers per frame stage.

Usage::

    PYTHONPATH=python python bench/bench_simulate.py [--frames 200] [--workers 2] [--scale 0.5]
        [--out DIR] [--keep]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np


def write_pictures(seq: Any, i: int, folder: Path) -> None:
    """RGB, label colours and the LiDAR scan projected with the manifest's calibration (colour =
    depth, blue near → red 8 m), side by side, as ``folder/frame_NNNNNN.png``."""
    import cv2

    from bimcap.geometry.poses import transform_points
    from bimcap.labels import LABEL_COLORS

    rgb = seq.load_image(i)
    lab = LABEL_COLORS[seq.load_labels(i)]
    pts = seq.load_lidar(i)
    p_cam = transform_points(seq.cam_from_lidar, pts[:, :3].astype(np.float64))
    uv, front = seq.camera.project(p_cam)
    ok = front & seq.camera.in_image(uv)
    overlay = rgb.copy()
    z8 = np.clip(p_cam[ok, 2] / 8.0 * 255.0, 0, 255).astype(np.uint8).reshape(-1, 1)
    colours = cv2.applyColorMap(z8, cv2.COLORMAP_JET).reshape(-1, 3)[:, ::-1]
    for (u, v), c in zip(np.rint(uv[ok]).astype(int), colours, strict=True):
        cv2.circle(overlay, (int(u), int(v)), 2, tuple(int(x) for x in c), -1)
    folder.mkdir(parents=True, exist_ok=True)
    strip = np.concatenate([rgb, lab, overlay], axis=1)
    cv2.imwrite(str(folder / f"frame_{i:06d}.png"), strip[:, :, ::-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1, help="ray-casting threads per worker")
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="work folder (default: a temp dir)")
    ap.add_argument("--keep", action="store_true", help="keep the sequence")
    ap.add_argument("--pictures", type=Path, default=None,
                    help="write RGB / label / LiDAR-overlay PNGs of a few frames into this folder")
    args = ap.parse_args(argv)

    from bimcap.sim.building import as_built, generate_building
    from bimcap.sim.simulator import (
        CONSLAM_CAMERA,
        SimulatorConfig,
        load_ifc_parts,
        sidecar_free_space,
        simulate_world,
    )

    work = args.out or Path(tempfile.mkdtemp(prefix="bimcap-bench-sim-"))
    work.mkdir(parents=True, exist_ok=True)
    rows: list[tuple[str, float]] = []
    t0 = time.perf_counter()
    design = generate_building(seed=args.seed, ifc_path=work / "design.ifc")
    as_built(design, seed=args.seed + 1, ifc_path=work / "asbuilt.ifc")
    rows.append(("generate building (IFC + as-built)", time.perf_counter() - t0))
    t0 = time.perf_counter()
    parts = load_ifc_parts(work / "asbuilt.ifc")
    side = sidecar_free_space(work / "asbuilt.ifc")
    assert side is not None
    polygons, z_floor = side
    rows.append(("load as-built IFC (bim.load_model)", time.perf_counter() - t0))

    cfg = replace(
        SimulatorConfig(), camera=CONSLAM_CAMERA.scaled(args.scale), frames=args.frames,
        workers=args.workers, threads_per_worker=args.threads, z_floor=z_floor,
    )
    seq_dir = work / "seq"
    if seq_dir.exists():
        shutil.rmtree(seq_dir)
    t0 = time.perf_counter()
    res = simulate_world(parts, seq_dir, cfg, args.seed, polygons, None, True, work / "design.ifc")
    total_sim = time.perf_counter() - t0
    t = res.timings
    rows += [
        ("  free space + clearance", t["free_space"]),
        ("  walk planning", t["walk"]),
        ("  clutter + world + texture bake", t["world"]),
        ("  render + LiDAR + write (wall)", t["render_wall"]),
        ("  manifest + gt.tum + validation", t["manifest"]),
        ("simulate total", total_sim),
    ]
    cam = cfg.camera
    print(f"bimcap simulate benchmark: {args.frames} frames {cam.width}x{cam.height} + VLP-16, "
          f"{args.workers} workers x {args.threads} threads, {os.cpu_count()} CPUs, "
          f"{res.world_triangles} triangles, {len(res.clutter)} clutter objects")
    print(f"{'stage':<40} {'wall s':>8}")
    for name, sec in rows:
        print(f"{name:<40} {sec:8.2f}")
    print(f"{'per frame, summed over workers':<40} {'wall s':>8} {'CPU s':>8}")
    for key, cpu_key in (("raycast", None), ("texture", None), ("shade", "image"),
                         ("lidar", "lidar"), ("write", "write")):
        cpu = "" if cpu_key is None else f"{t['cpu_' + cpu_key] / args.frames:8.3f}"
        label = key if cpu_key != "image" else "shade   (CPU: raycast+texture+shade)"
        print(f"  {label:<38} {t['sum_' + key] / args.frames:8.3f} {cpu:>8}")
    cpu_total = sum(t[k] for k in ("cpu_image", "cpu_lidar", "cpu_write"))
    serial = total_sim - t["render_wall"]
    est = serial + cpu_total / max(1, min(args.workers or os.cpu_count() or 1, 2))
    print(f"frames per second (wall): {args.frames / t['render_wall']:.2f}; load average now "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"measured wall: {total_sim:.1f} s for {args.frames} frames "
          f"-> {total_sim * 200 / args.frames:.1f} s per 200 frames")
    per200 = serial + (est - serial) * 200 / args.frames
    print(f"CPU-time estimate on 2 idle cores: serial {serial:.1f} s + render CPU "
          f"{cpu_total:.1f} s / 2 = {est:.1f} s -> {per200:.1f} s per 200 frames (target < 60 s)")
    size = sum(p.stat().st_size for p in seq_dir.rglob("*") if p.is_file())
    print(f"sequence size: {size / 1e6:.1f} MB in {seq_dir}")
    if args.pictures is not None:
        for i in np.linspace(0, args.frames - 1, 4).astype(int):
            write_pictures(res.sequence, int(i), args.pictures)
        print(f"pictures in {args.pictures}")
    if not args.keep and args.out is None:
        shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
