"""Solver benchmarks (a plain script, never collected by pytest). Prints tables.

1. scaling: solve time, iterations and peak RSS for 100 / 300 / 1000 frames at ~1000 residuals
   per frame (~10⁶ at 1000 frames), all terms, ROBUST weighting;
2. landmark BA against pycolmap.bundle_adjustment on the identical problem (same observations,
   frame 0 fixed, intrinsics fixed, plain L2, same tolerances);
3. the paper objective (PAPER weighting, G point + F + Ce + W with the association of the initial
   poses) against the peers' optimiser re-implemented in numpy — full-batch SGD, learning rate
   0.1, momentum 0.9 — and against scipy.optimize.least_squares with a sparse Jacobian;
4. problem files (``--problems P.bimcap ...``, e.g. written from inside ``bimcap refine`` with
   ``bimcap.optimize.write_problem``): each solved with the options written in it (the peer:
   refine's batching when the file was written) and with today's batching (``batch_size`` and
   ``compress_batches`` of ``SolverOptions()``, what ``bimcap refine`` uses now; ``--peer-rows``:
   one row per residual as the peer instead), alternating in this process; wall and CPU seconds
   against the goal (1000 frames in 5 s), the ratio, and how far the two results' poses are
   apart.

Usage::

    PYTHONPATH=python python bench/bench_solver.py                       # everything, full sizes
    PYTHONPATH=python python bench/bench_solver.py --sizes 100 300 --sgd-iterations 20000 \
        --peer-frames 30
    PYTHONPATH=python python bench/bench_solver.py --skip scaling pycolmap peers \
        --problems p_0.bimcap p_1.bimcap --repeats 2
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from bimcap.optimize import GeometricMode, Loss, SolverOptions, solve
from bimcap.optimize.synthetic import SyntheticConfig, make_synthetic_problem, pose_errors

#: per-frame counts for ~1000 scalar residuals per frame
DENSE = {"matches_per_pair": 120, "floor_per_frame": 100, "ceiling_per_frame": 60,
         "wall_per_frame": 150, "column_per_frame": 30, "landmarks_per_frame": 0,
         "drift_translation_sigma": 0.02, "drift_yaw_sigma_deg": 0.2}


# ----------------------------------------------------------------------------------- scaling
def _scaling_child(frames: int, queue: Any) -> None:
    s = make_synthetic_problem(num_frames=frames, seed=1, **DENSE)
    before = resource.getrusage(resource.RUSAGE_SELF)
    base = before.ru_maxrss
    r = solve(s.problem, SolverOptions(num_threads=2), check=False)
    after = resource.getrusage(resource.RUSAGE_SELF)
    peak = after.ru_maxrss
    # CPU seconds of the solve (all threads): less sensitive than wall time to a loaded machine.
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    t0, r0 = pose_errors(s.problem.poses, s.gt_poses)
    t1, r1 = pose_errors(r.poses, s.gt_poses)
    queue.put({"frames": frames, "residuals": r.summary.num_residuals, "time": r.summary.time_s,
               "cpu": cpu, "cost": r.summary.final_cost, "ceres": r.summary.ceres_time_s,
               "iters": r.summary.iterations, "rounds": r.summary.outer_iterations,
               "rss": peak / 1024, "rss_solve": (peak - base) / 1024, "err": (t0, r0, t1, r1),
               "term": r.summary.termination})


def bench_scaling(sizes: list[int]) -> None:
    print("\n## Scaling (all terms, ROBUST/Huber, 2 threads; each size in a fresh process)")
    print(f"{'frames':>6} {'residuals':>10} {'time s':>8} {'ceres s':>8} {'cpu s':>7} {'iters':>6} "
          f"{'rounds':>6} {'final cost':>18} {'peak RSS MB':>11} {'error before -> after':>34}")
    ctx = mp.get_context("fork")
    for n in sizes:
        q = ctx.Queue()
        p = ctx.Process(target=_scaling_child, args=(n, q))
        p.start()
        row = q.get()
        p.join()
        t0, r0, t1, r1 = row["err"]
        print(f"{row['frames']:6d} {row['residuals']:10d} {row['time']:8.2f} {row['ceres']:8.2f} "
              f"{row['cpu']:7.2f} {row['iters']:6d} {row['rounds']:6d} {row['cost']:18.12g} "
              f"{row['rss']:11.0f} {t0:8.3f} m {r0:5.2f}° -> {t1:6.4f} m {r1:5.3f}°")


# -------------------------------------------------------------------------------- pycolmap BA
def bench_pycolmap(frames: int) -> None:
    print(f"\n## Landmark BA vs pycolmap.bundle_adjustment ({frames} frames, poses + points, "
          f"frame 0 fixed, L2)")
    try:
        import pycolmap
    except ImportError:
        print("skipped: pycolmap not installed")
        return
    s = make_synthetic_problem(num_frames=frames, seed=4, landmarks_per_frame=40,
                               matches_per_pair=0, floor_per_frame=0, ceiling_per_frame=0,
                               wall_per_frame=0, column_per_frame=0,
                               drift_translation_sigma=0.01, drift_yaw_sigma_deg=0.1)
    # COLMAP refuses tracks of length 1: keep the landmarks seen at least twice, in both solvers.
    p = s.problem
    counts = np.bincount(p.track_obs_point, minlength=len(p.track_points))
    keep_obs = counts[p.track_obs_point] >= 2
    keep_pts = np.flatnonzero(counts >= 2)
    remap = np.full(len(p.track_points), -1, dtype=np.int32)
    remap[keep_pts] = np.arange(len(keep_pts), dtype=np.int32)
    p = type(p).from_arrays({**p.arrays(), "track_obs_frame": p.track_obs_frame[keep_obs],
                             "track_obs_point": remap[p.track_obs_point[keep_obs]],
                             "track_obs_uv": p.track_obs_uv[keep_obs],
                             "track_obs_depth": p.track_obs_depth[keep_obs],
                             "track_points": p.track_points[keep_pts]})
    tol = {"function_tolerance": 1e-6, "gradient_tolerance": 1e-10, "parameter_tolerance": 1e-8,
           "max_iterations": 100}
    opts = SolverOptions(geometric_mode=GeometricMode.LANDMARK, num_threads=2,
                         **tol).with_terms("G")
    opts.depth.enabled = False
    opts.geometric.loss = Loss.NONE
    t = time.perf_counter()
    ours = solve(p, opts)
    t_ours = time.perf_counter() - t
    ours_cost = ours.summary.final_cost * opts.pixel_sigma**2  # ½ Σ r² in px²

    try:
        rec = pycolmap.Reconstruction()
        k = p.cameras[0]
        cam = pycolmap.Camera(model="PINHOLE", width=640, height=480, params=k, camera_id=1)
        rec.add_camera_with_trivial_rig(cam)
        cam_from_world = Rotation.from_quat(p.poses[:, 3:]).inv()
        per_frame: list[list[int]] = [[] for _ in range(p.num_poses)]
        for obs, f in enumerate(p.track_obs_frame):
            per_frame[f].append(obs)
        point2d_index = np.zeros(len(p.track_obs_frame), dtype=np.int64)
        for i in range(p.num_poses):
            idx = per_frame[i]
            point2d_index[idx] = np.arange(len(idx))
            image = pycolmap.Image(name=f"{i:06d}", keypoints=p.track_obs_uv[idx], camera_id=1,
                                   image_id=i + 1)
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(cam_from_world[i].as_quat()),
                                    -cam_from_world[i].apply(p.poses[i, :3]))
            rec.add_image_with_trivial_frame(image, pose)
        order = np.argsort(p.track_obs_point, kind="stable")
        starts = np.searchsorted(p.track_obs_point[order], np.arange(len(p.track_points) + 1))
        for j in range(len(p.track_points)):
            track = pycolmap.Track()
            for obs in order[starts[j]:starts[j + 1]]:
                track.add_element(int(p.track_obs_frame[obs]) + 1, int(point2d_index[obs]))
            rec.add_point3D(p.track_points[j], track)
        ba = pycolmap.BundleAdjustmentOptions()
        ba.refine_focal_length = False
        ba.refine_principal_point = False
        ba.refine_extra_params = False
        ba.print_summary = False
        so = ba.ceres.solver_options
        so.function_tolerance, so.gradient_tolerance, so.parameter_tolerance = 1e-6, 1e-10, 1e-8
        so.max_num_iterations = 100
        so.num_threads = 2
        config = pycolmap.BundleAdjustmentConfig()
        for i in range(p.num_poses):
            config.add_image(i + 1)
        config.set_constant_rig_from_world_pose(1)  # frame 0, as bimcap's pose_fixed
        config.set_constant_cam_intrinsics(1)
        adjuster = pycolmap.create_default_bundle_adjuster(ba, config, rec)
        t = time.perf_counter()
        summary = adjuster.solve()
        t_colmap = time.perf_counter() - t
        colmap_cost = getattr(summary, "final_cost", float("nan"))
        if hasattr(summary, "ceres_summary"):
            colmap_cost = summary.ceres_summary.final_cost
        est = np.empty_like(p.poses)
        for i in range(p.num_poses):
            cfw = rec.image(i + 1).cam_from_world()
            wfc = cfw.inverse()
            est[i, :3] = wfc.translation
            est[i, 3:] = wfc.rotation.quat
    except Exception as exc:  # report and go on: a bench, not a test
        print(f"pycolmap part failed: {type(exc).__name__}: {exc}")
        print(f"bimcap: {t_ours:.3f} s, final ½Σr² {ours_cost:.6g} px², "
              f"{ours.summary.iterations} iterations")
        return
    print(f"{'':10} {'time s':>8} {'final ½Σr² px²':>16} {'pose err m/deg':>18}")
    te, re_ = pose_errors(ours.poses, s.gt_poses)
    print(f"{'bimcap':10} {t_ours:8.3f} {ours_cost:16.8g} {te:9.4f} {re_:7.3f}")
    tc, rc = pose_errors(est, s.gt_poses)
    print(f"{'pycolmap':10} {t_colmap:8.3f} {colmap_cost:16.8g} {tc:9.4f} {rc:7.3f}")
    print(f"time ratio bimcap / pycolmap = {t_ours / t_colmap:.2f}; relative cost difference = "
          f"{(ours_cost - colmap_cost) / colmap_cost:.2e} ({len(p.track_obs_frame)} observations, "
          f"{len(p.track_points)} points)")


# ------------------------------------------------------------------------- paper objective
class PaperObjective:
    """The peers' objective Σ λ · mean ‖r‖² over G (point), F, Ce, W, with fixed W association.

    Variables: per free pose a translation and a left rotation increment (R = Exp(ω) R0).
    """

    def __init__(self, p: Any, wall_segment: np.ndarray) -> None:
        self.p = p
        k = p.cameras[0]
        d = p.match_depth
        uv = p.match_uv
        self.ga = np.column_stack([(uv[:, 0] - k[2]) / k[0] * d[:, 0],
                                   (uv[:, 1] - k[3]) / k[1] * d[:, 0], d[:, 0]])
        self.gb = np.column_stack([(uv[:, 2] - k[2]) / k[0] * d[:, 1],
                                   (uv[:, 3] - k[3]) / k[1] * d[:, 1], d[:, 1]])
        keep = wall_segment >= 0
        self.w_frame = p.wall_frame[keep]
        self.w_p = p.wall_p_in_cam[keep]
        self.w_seg = p.segments[wall_segment[keep]]
        self.lam = {"G": 1.0, "F": 0.02, "Ce": 0.02, "W": 0.0007}
        self.n = {"G": len(self.ga), "F": len(p.floor_frame), "Ce": len(p.ceiling_frame),
                  "W": len(self.w_frame)}
        self.free = p.pose_fixed == 0
        self.r0 = Rotation.from_quat(p.poses[:, 3:])
        self.t0 = p.poses[:, :3].copy()

    def poses(self, x: np.ndarray) -> np.ndarray:
        x = x.reshape(-1, 6)
        out = self.p.poses.copy()
        out[:, :3] = self.t0 + x[:, :3]
        out[:, 3:] = (Rotation.from_rotvec(x[:, 3:]) * self.r0).as_quat()
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """sqrt(λ/N)-scaled residuals: Σ r² is the paper objective."""
        poses = self.poses(x)
        rot = Rotation.from_quat(poses[:, 3:])
        p = self.p
        mf = p.match_frames

        def world(frames: np.ndarray, pts: np.ndarray) -> np.ndarray:
            return rot[frames].apply(pts) + poses[frames, :3]

        g = (world(mf[:, 0], self.ga) - world(mf[:, 1], self.gb)).ravel()
        fw = world(p.floor_frame, p.floor_p_in_cam)
        fr = np.einsum("ij,ij->i", fw, p.planes[p.floor_plane, :3]) + p.planes[p.floor_plane, 3]
        cw = world(p.ceiling_frame, p.ceiling_p_in_cam)
        cr = np.einsum("ij,ij->i", cw, p.planes[p.ceiling_plane, :3]) + p.planes[p.ceiling_plane, 3]
        ww = world(self.w_frame, self.w_p)
        wr = _segment_distance(ww[:, :2], self.w_seg)
        s = {k: np.sqrt(self.lam[k] / self.n[k]) for k in self.lam}
        return np.concatenate([s["G"] * g, s["F"] * fr, s["Ce"] * cr, s["W"] * wr])

    def value_and_gradient(self, poses: np.ndarray) -> tuple[float, np.ndarray]:
        """Objective and its gradient w.r.t. [δt, δθ] (left increments) of every pose, (N, 6)."""
        rot = Rotation.from_quat(poses[:, 3:])
        p = self.p
        grad = np.zeros((len(poses), 6))
        total = 0.0

        def accumulate(frames: np.ndarray, q_rot: np.ndarray, dr_dp: np.ndarray, r: np.ndarray,
                       w: float) -> None:
            # r: (M, D), dr_dp: (M, D, 3) derivative w.r.t. the world point; f = w Σ r².
            gp = 2.0 * w * np.einsum("md,mdk->mk", r, dr_dp)  # df/dp_world (M, 3)
            np.add.at(grad[:, :3], frames, gp)
            np.add.at(grad[:, 3:], frames, np.cross(q_rot, gp))  # d/dδ of p = δ×q: (q × gp)

        mf = p.match_frames
        qa, qb = rot[mf[:, 0]].apply(self.ga), rot[mf[:, 1]].apply(self.gb)
        r = qa + poses[mf[:, 0], :3] - qb - poses[mf[:, 1], :3]
        w = self.lam["G"] / self.n["G"]
        total += w * np.sum(r**2)
        eye = np.broadcast_to(np.eye(3), (len(r), 3, 3))
        accumulate(mf[:, 0], qa, eye, r, w)
        accumulate(mf[:, 1], qb, -eye, r, w)
        for name, frames, pts, plane in (
                ("F", p.floor_frame, p.floor_p_in_cam, p.floor_plane),
                ("Ce", p.ceiling_frame, p.ceiling_p_in_cam, p.ceiling_plane)):
            q = rot[frames].apply(pts)
            n = p.planes[plane, :3]
            res = (np.einsum("ij,ij->i", q + poses[frames, :3], n) + p.planes[plane, 3])[:, None]
            w = self.lam[name] / self.n[name]
            total += w * np.sum(res**2)
            accumulate(frames, q, n[:, None, :], res, w)
        q = rot[self.w_frame].apply(self.w_p)
        xy = (q + poses[self.w_frame, :3])[:, :2]
        res, dxy = _segment_distance(xy, self.w_seg, gradient=True)
        w = self.lam["W"] / self.n["W"]
        total += w * np.sum(res**2)
        d3 = np.concatenate([dxy, np.zeros((len(dxy), 1))], axis=1)[:, None, :]
        accumulate(self.w_frame, q, d3, res[:, None], w)
        grad[~self.free] = 0.0
        return total, grad


def _segment_distance(xy: np.ndarray, seg: np.ndarray, gradient: bool = False) -> Any:
    a, b = seg[:, :2], seg[:, 2:]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    e = xy - a
    along = np.einsum("ij,ij->i", e, d) / length**2
    cross = (d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]) / length
    end = np.where((along > 1)[:, None], xy - b, e)
    end_norm = np.linalg.norm(end, axis=1)
    inside = (along >= 0) & (along <= 1)
    sign = np.where(cross < 0, -1.0, 1.0)
    r = np.where(inside, cross, sign * end_norm)
    if not gradient:
        return r
    g_inside = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    g_end = sign[:, None] * end / np.maximum(end_norm, 1e-12)[:, None]
    return r, np.where(inside[:, None], g_inside, g_end)


def sgd(obj: PaperObjective, iterations: int, lr: float = 0.1,
        momentum: float = 0.9) -> tuple[np.ndarray, float, float]:
    """The peers' optimiser: full-batch SGD with momentum on [t, rotation increment]."""
    poses = obj.p.poses.copy()
    velocity = np.zeros((len(poses), 6))
    start = time.perf_counter()
    for _ in range(iterations):
        _, g = obj.value_and_gradient(poses)
        velocity = momentum * velocity + g  # torch.optim.SGD semantics
        step = -lr * velocity
        poses[:, :3] += step[:, :3]
        poses[:, 3:] = (Rotation.from_rotvec(step[:, 3:])
                        * Rotation.from_quat(poses[:, 3:])).as_quat()
    elapsed = time.perf_counter() - start
    return poses, obj.value_and_gradient(poses)[0], elapsed


def bench_peers(frames: int, sgd_iterations: int) -> None:
    print(f"\n## Paper objective (G point + F + Ce + W, PAPER weighting): {frames} frames")
    s = make_synthetic_problem(num_frames=frames, seed=6, matches_per_pair=60, floor_per_frame=60,
                               ceiling_per_frame=40, wall_per_frame=80, column_per_frame=0,
                               landmarks_per_frame=0,
                               drift_translation_sigma=0.02, drift_yaw_sigma_deg=0.2)
    p = s.problem
    opts = SolverOptions.paper(outer_iterations=1, num_threads=2).with_terms("G+F+Ce+W")
    # The association at the initial poses (no iteration), held fixed for every method.
    initial = solve(p, SolverOptions.paper(outer_iterations=1, max_iterations=0)
                    .with_terms("G+F+Ce+W"))
    obj = PaperObjective(p, initial.wall_segment)
    t = time.perf_counter()
    ours = solve(p, opts)
    t_ours = time.perf_counter() - t
    f0, _ = obj.value_and_gradient(p.poses)
    f_ours, _g_ours = obj.value_and_gradient(ours.poses)
    print(f"initial objective {f0:.8g}; bimcap reports {ours.summary.initial_paper_objective:.8g} "
          f"(numpy formula vs C++: rel diff "
          f"{abs(f0 - ours.summary.initial_paper_objective) / f0:.1e})")
    rows = [("bimcap (Ceres LM)", t_ours, f_ours, ours.summary.iterations, ours.poses)]

    x0 = np.zeros(6 * p.num_poses)
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    n_res = len(obj.residuals(x0))
    sparsity = lil_matrix((n_res, 6 * p.num_poses), dtype=np.int8)
    row = 0
    for frames in (p.match_frames[:, 0], p.match_frames[:, 1]):
        for j in range(3):
            for k in range(6):
                sparsity[np.arange(len(frames)) * 3 + j, frames * 6 + k] = 1
    row = 3 * len(p.match_frames)
    for frames in (p.floor_frame, p.ceiling_frame, obj.w_frame):
        for k in range(6):
            sparsity[row + np.arange(len(frames)), frames * 6 + k] = 1
        row += len(frames)
    fixed = np.flatnonzero(p.pose_fixed)
    for i in fixed:
        sparsity[:, i * 6 : i * 6 + 6] = 0
    free_cols = np.flatnonzero(np.repeat(p.pose_fixed == 0, 6))
    sp = sparsity.tocsr()[:, free_cols]

    def fun(xf: np.ndarray) -> np.ndarray:
        x = np.zeros(6 * p.num_poses)
        x[free_cols] = xf
        return obj.residuals(x)

    t = time.perf_counter()
    ls = least_squares(fun, np.zeros(len(free_cols)), jac_sparsity=sp, method="trf", x_scale="jac",
                       ftol=1e-8, xtol=1e-10, gtol=1e-10)
    t_ls = time.perf_counter() - t
    x = np.zeros(6 * p.num_poses)
    x[free_cols] = ls.x
    ls_poses = obj.poses(x)
    rows.append(("scipy least_squares (trf, sparse)", t_ls, obj.value_and_gradient(ls_poses)[0],
                 ls.nfev, ls_poses))

    sgd_poses, f_sgd, t_sgd = sgd(obj, sgd_iterations)
    rows.append((f"peers: SGD lr 0.1 m 0.9 × {sgd_iterations}", t_sgd, f_sgd, sgd_iterations,
                 sgd_poses))

    print(f"{'method':38} {'time s':>9} {'final objective':>16} {'iters':>7} "
          f"{'pose err m/deg':>18}")
    for name, tt, f, it, poses in rows:
        te, re_ = pose_errors(poses, s.gt_poses)
        print(f"{name:38} {tt:9.3f} {f:16.10g} {it:7d} {te:9.4f} {re_:7.3f}")
    print(f"speed ratio SGD / bimcap = {t_sgd / t_ours:.0f}×; "
          f"scipy / bimcap = {t_ls / t_ours:.1f}×; "
          f"final objective bimcap − SGD = {f_ours - f_sgd:.3e} "
          f"(≤ 0 means bimcap reached the same or lower cost)")


# ----------------------------------------------------------------------------- problem files
def bench_problems(paths: list[str], repeats: int, peer_rows: bool = False) -> None:
    from dataclasses import replace

    from bimcap.optimize import read_problem

    today = SolverOptions()
    peer_name = "rows" if peer_rows else "as written"
    print(f"\n## Problem files: today's batching (batch_size {today.batch_size}, compressed "
          f"{today.compress_batches}) vs the peer ({peer_name}), alternating in one process "
          "(wall s, CPU s of the process; goal: 5 s wall per 1000 poses)")
    print(f"{'problem':28} {'poses':>5} {'residuals':>10} {'form':>22} {'wall s':>7} {'cpu s':>7} "
          f"{'iters':>5} {'rounds':>6} {'final cost':>16} {'goal s':>6}")
    for path in paths:
        problem, options = read_problem(path)
        forms = {
            "peer": (replace(options, compress_batches=False) if peer_rows else options),
            "today": replace(options, batch_size=today.batch_size,
                             compress_batches=today.compress_batches),
        }
        runs: dict[str, list[tuple[float, float, Any]]] = {"peer": [], "today": []}
        for _ in range(repeats):
            for form, opts in forms.items():
                before = resource.getrusage(resource.RUSAGE_SELF)
                t = time.perf_counter()
                r = solve(problem, opts, check=False)
                wall = time.perf_counter() - t
                after = resource.getrusage(resource.RUSAGE_SELF)
                cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
                runs[form].append((wall, cpu, r))
                goal = 5.0 * problem.num_poses / 1000.0
                label = (f"{form}: {'rows' if not opts.compress_batches else 'batch'} "
                         f"{opts.batch_size}")
                print(f"{path[-28:]:28} {problem.num_poses:5d} {r.summary.num_residuals:10d} "
                      f"{label:>22} {wall:7.2f} {cpu:7.2f} "
                      f"{r.summary.iterations:5d} {r.summary.outer_iterations:6d} "
                      f"{r.summary.final_cost:16.9g} {goal:6.2f}")
        best = {f: min(runs[f], key=lambda x: x[0]) for f in runs}
        a, b = best["peer"][2].poses, best["today"][2].poses
        dt = float(np.abs(a[:, :3] - b[:, :3]).max())
        dq = float(np.abs(np.abs((a[:, 3:] * b[:, 3:]).sum(axis=1)) - 1.0).max())
        print(f"  best wall: peer {best['peer'][0]:.2f} s, today {best['today'][0]:.2f} s "
              f"(goal {5.0 * problem.num_poses / 1000.0:.2f}), ratio "
              f"{best['peer'][0] / best['today'][0]:.2f}×; poses apart by at most {dt:.2e} m "
              f"(1 − |q·q'| ≤ {dq:.1e})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[100, 300, 1000])
    ap.add_argument("--ba-frames", type=int, default=100)
    ap.add_argument("--peer-frames", type=int, default=60)
    ap.add_argument("--sgd-iterations", type=int, default=20000)
    ap.add_argument("--skip", nargs="*", default=[], choices=["scaling", "pycolmap", "peers"])
    ap.add_argument("--problems", nargs="*", default=[], help="problem files to solve both ways")
    ap.add_argument("--repeats", type=int, default=1, help="alternations per problem file")
    ap.add_argument("--peer-rows", action="store_true",
                    help="problem files: one row per residual as the peer, not the file's options")
    args = ap.parse_args()
    print(f"bimcap solver benchmark — {time.strftime('%Y-%m-%d %H:%M:%S')}, "
          f"SyntheticConfig defaults: {SyntheticConfig().intrinsics}")
    if "scaling" not in args.skip:
        bench_scaling(args.sizes)
    if "pycolmap" not in args.skip:
        bench_pycolmap(args.ba_frames)
    if "peers" not in args.skip:
        bench_peers(args.peer_frames, args.sgd_iterations)
    if args.problems:
        bench_problems(args.problems, args.repeats, args.peer_rows)


if __name__ == "__main__":
    main()
