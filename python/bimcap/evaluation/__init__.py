"""Metrics (ATE, yaw/pitch/roll, MME, MPV, NND) and plots.

Modules (imported explicitly; nothing heavy is imported here):

- :mod:`bimcap.evaluation.metrics`: ``evaluate_trajectory(est, gt, align, max_dt)`` on
  :class:`~bimcap.geometry.trajectory.Trajectory` objects, ``trajectory_metrics(est, gt, align)``
  on matched (N, 7) arrays, ``associate``, ``frame_errors``, ``AlignMode``,
  ``TrajectoryMetrics`` / ``ErrorStats`` / ``FrameErrors``. ATE equals evo's ``APE``.
- :mod:`bimcap.evaluation.map_metrics`: ``aggregate_map(scans, world_from_sensor)``,
  ``map_metrics(points, radius, min_neighbours)`` (MME/MPV equal to the map-metrics package),
  ``nearest_neighbour_distance``, ``map_metrics_with_reference``, ``read_ply_points``,
  ``MapMetrics``, ``CutoffMode``.
- :mod:`bimcap.evaluation.alignment`: ``umeyama_alignment`` (evo's SE(3)/Sim(3)), ``Similarity``.
- :mod:`bimcap.evaluation.plots`: ``plot_trajectories_on_plan`` (with camera headings),
  ``plot_errors_per_frame`` (``error_limits`` for a shared scale), ``plot_errors_on_plan``,
  ``plot_maps_on_plan``, ``plot_side_view``, ``plot_map_3d``, ``plot_term_costs``,
  ``plot_observability``; ``run_colour`` / ``RUN_PALETTE`` (one colour per run on every figure;
  matplotlib Agg; atomic PNG writes).
- :mod:`bimcap.evaluation.errors`: ``EvaluationError``.
"""
