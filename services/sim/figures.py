"""The paper's figures from a simulated run: Fig. 11 paths, Fig. 12 leader tracking error,
Fig. 13 follower formation errors.  Errors come from the metrics module (ground truth)."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from swarm_config.atomic_files import write_file_atomically
from swarm_config.scenario import Scenario
from world.metrics import FormationLayout, reference_points

FloatArray = NDArray[np.float64]
ROBOT_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2")


def save_figure(figure: Figure, path: Path, **savefig_options: Any) -> Path:
    """Render `figure` as PNG and put it at `path` in one rename, then close it: a killed or
    starved process never leaves half an image; FileWriteError when it cannot be written."""
    image = io.BytesIO()
    try:
        figure.savefig(image, format="png", **savefig_options)
    finally:
        plt.close(figure)
    write_file_atomically(path, image.getvalue())
    return path


def colour(index: int) -> str:
    return ROBOT_COLOURS[index % len(ROBOT_COLOURS)]


PATHS_FIGURE = "fig11_paths.png"
LEADER_ERROR_FIGURE = "fig12_leader_tracking_error.png"
FORMATION_ERRORS_FIGURE = "fig13_formation_errors.png"
FIGURE_NAMES = (PATHS_FIGURE, LEADER_ERROR_FIGURE, FORMATION_ERRORS_FIGURE)
"""The files `write_figures` writes in its folder."""


def write_figures(
    scenario: Scenario, trace: dict[str, FloatArray], out_dir: Path, batch_index: int = 0
) -> list[Path]:
    """Write the three PNGs into out_dir and return their paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    t = trace["t_s"]
    pose = trace["true_pose"][:, batch_index]
    errors = trace["errors"][:, batch_index]
    names = scenario.robot_names
    layout = FormationLayout.from_scenario(scenario)
    lead = layout.leader_index
    paths = [
        _paths_figure(scenario, t, pose, trace["trajectory_pose"], out_dir),
        _leader_error_figure(t, errors[:, lead], names[lead], out_dir),
        _formation_error_figure(t, errors, layout.follower_indices, names, out_dir),
    ]
    return paths


def _paths_figure(
    scenario: Scenario, t: FloatArray, pose: FloatArray, reference: FloatArray, out_dir: Path
) -> Path:
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.plot(reference[:, 0], reference[:, 1], "k--", lw=1, label="leader reference")
    layout = FormationLayout.from_scenario(scenario)
    slots = reference_points(pose, reference, layout)
    for i, name in enumerate(scenario.robot_names):
        role = "leader" if i == layout.leader_index else "follower"
        ax.plot(pose[:, i, 0], pose[:, i, 1], color=colour(i), lw=1.2, label=f"{name} ({role})")
        ax.plot(pose[0, i, 0], pose[0, i, 1], "o", color=colour(i), ms=6)
    radius = scenario.robot_body.body_radius_m
    for k in np.linspace(0, len(t) - 1, 7).astype(int)[1:]:
        tri = np.vstack([pose[k, :, :2], pose[k, :1, :2]])
        ax.plot(tri[:, 0], tri[:, 1], color="0.5", lw=0.6)
        for i in range(pose.shape[1]):
            ax.add_patch(plt.Circle(tuple(pose[k, i, :2]), radius, fill=False, color=colour(i)))
            if i != layout.leader_index:
                ax.plot(slots[k, i, 0], slots[k, i, 1], "x", color=colour(i), ms=5)
    for j, obstacle in enumerate(scenario.obstacles):
        label = "obstacle" if j == 0 else None
        ax.add_patch(plt.Circle(obstacle.position_m, obstacle.radius_m, color="0.2", label=label))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Fig. 11: paths ({scenario.name}); circles: bodies, x: formation slots")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(True, lw=0.3)
    return save_figure(fig, out_dir / PATHS_FIGURE, dpi=110, bbox_inches="tight")


def _leader_error_figure(t: FloatArray, errors: FloatArray, name: str, out_dir: Path) -> Path:
    fig, (ax_xy, ax_th) = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
    ax_xy.plot(t, errors[:, 0], label="x_e")
    ax_xy.plot(t, errors[:, 1], label="y_e")
    ax_xy.set_ylabel("position error (m)")
    ax_xy.legend(fontsize=8)
    ax_xy.grid(True, lw=0.3)
    ax_th.plot(t, errors[:, 2], color="tab:purple", label="θ_e")
    ax_th.set_ylabel("heading error (rad)")
    ax_th.set_xlabel("t (s)")
    ax_th.grid(True, lw=0.3)
    ax_xy.set_title(f"Fig. 12: tracking error of the leader {name}")
    return save_figure(fig, out_dir / LEADER_ERROR_FIGURE, dpi=110, bbox_inches="tight")


def _formation_error_figure(
    t: FloatArray,
    errors: FloatArray,
    followers: tuple[int, ...],
    names: tuple[str, ...],
    out_dir: Path,
) -> Path:
    fig, ax = plt.subplots(figsize=(8, 4))
    for i in followers:
        ax.plot(t, errors[:, i, 0], color=colour(i), lw=1, label=f"{names[i]} x_e")
        ax.plot(t, errors[:, i, 1], color=colour(i), lw=1, ls="--", label=f"{names[i]} y_e")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("formation error (m)")
    ax.set_title("Fig. 13: formation errors of the followers (slot from the leader's true pose)")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(True, lw=0.3)
    return save_figure(fig, out_dir / FORMATION_ERRORS_FIGURE, dpi=110, bbox_inches="tight")
