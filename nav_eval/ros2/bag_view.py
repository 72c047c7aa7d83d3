"""`segmin ros2 view-bag`: one picture of a bag's topics, the panels a viewer such as Foxglove shows.

A build machine, a CI runner or a robot over SSH has no GUI viewer; this renders with matplotlib
what Foxglove's Image, Plot and Map panels would show for segmin's topics (`topics`): the colour
frame nearest a chosen time (with the mask of `--model` over it when one is given: the mask the
node would compute), the aligned depth in metres, `/cmd_vel` over the whole bag, and the
top-down path of `/odom` with the robot's position at that frame. It is segmin's rendering of the
recorded messages, not a screenshot of a viewer. Needs the [ros] extra (rosbags) and matplotlib.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from segmin.data.overlay import GREEN, tint_mask
from segmin.nav_eval.replay.bags import open_bag
from segmin.nav_eval.replay.ros_images import decode_colour, decode_depth, stamp_seconds
from segmin.nav_eval.ros2 import topics


@dataclass(frozen=True)
class BagView:
    """What the picture shows, read from the bag (times in seconds from the bag's first message)."""

    frame_t: float  # the shown frame's header stamp, from the bag's start
    rgb: np.ndarray
    depth: np.ndarray | None  # metres, NaN where the camera had no reading
    commands: np.ndarray  # (N, 3): t, v, omega of /cmd_vel
    path: np.ndarray  # (M, 3): t, x, y of /odom


def read_bag_view(
    bag: Path, at_s: float, colour_topic: str = topics.COLOUR, depth_topic: str = topics.DEPTH
) -> BagView:
    """The frame of `colour_topic` nearest `at_s` seconds into the bag, its depth, the commands and the path.

    ValueError (naming the bag and listing its topics) when it has no `colour_topic`; depth,
    commands and odometry are shown when present."""
    reader = open_bag(bag)
    try:
        if colour_topic not in reader.topics:
            have = ", ".join(sorted(reader.topics))
            raise ValueError(f"--bag {bag}: no topic {colour_topic!r} (--colour-topic); the bag has: {have}")
        wanted = [c for c in reader.connections if c.topic in (colour_topic, depth_topic, topics.CMD_VEL, topics.ODOM)]
        start = reader.start_time * 1e-9
        best: tuple[float, Any] | None = None
        depths: dict[float, Any] = {}
        commands, path = [], []
        for connection, t_ns, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            t = t_ns * 1e-9 - start
            if connection.topic == colour_topic:
                if best is None or abs(t - at_s) < abs(best[0] - at_s):
                    best = (t, message)
            elif connection.topic == depth_topic:
                depths[stamp_seconds(message)] = message
            elif connection.topic == topics.CMD_VEL:
                commands.append((t, message.linear.x, message.angular.z))
            else:
                path.append((t, message.pose.pose.position.x, message.pose.pose.position.y))
    finally:
        reader.close()
    assert best is not None  # the topic is in the bag, so it has a message
    frame_t, colour = best
    stamp = stamp_seconds(colour)
    depth_message = min(depths.items(), key=lambda item: abs(item[0] - stamp), default=(None, None))[1]
    depth = None
    if depth_message is not None:
        depth, _ = decode_depth(depth_message, depth_topic)
        depth = np.where(depth > 0, depth, np.nan)
    return BagView(
        frame_t=frame_t,
        rgb=decode_colour(colour, colour_topic),
        depth=depth,
        commands=np.asarray(commands, dtype=float).reshape(-1, 3),
        path=np.asarray(path, dtype=float).reshape(-1, 3),
    )


def plot_bag_view(view: BagView, title: str, mask: np.ndarray | None = None) -> bytes:
    """The four panels as a PNG (colour with the mask, depth, commands, path)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7.5))
    colour_ax, depth_ax, command_ax, path_ax = axes.ravel()
    colour_ax.imshow(view.rgb if mask is None else tint_mask(view.rgb, mask, GREEN, opacity=0.45))
    colour_ax.set_title(f"{topics.COLOUR} at {view.frame_t:.2f} s" + (" + mask" if mask is not None else ""))
    depth_ax.set_title(f"{topics.DEPTH} (m)")
    if view.depth is not None:
        image = depth_ax.imshow(view.depth, cmap="turbo")
        fig.colorbar(image, ax=depth_ax, fraction=0.046)
    for ax in (colour_ax, depth_ax):
        ax.set_xticks([])
        ax.set_yticks([])
    t, v, omega = view.commands.T
    command_ax.step(t, v, where="post", label="v (m/s)")
    command_ax.step(t, omega, where="post", label="omega (rad/s)")
    command_ax.axvline(view.frame_t, color="grey", linestyle=":")
    command_ax.set(title=topics.CMD_VEL, xlabel="time (s)")
    command_ax.legend(loc="lower right")
    command_ax.grid(alpha=0.3)
    if len(view.path):
        _, x, y = view.path.T
        path_ax.plot(x, y, label=f"{topics.ODOM} ({topics.ODOM_FRAME})")
        here = int(np.argmin(np.abs(view.path[:, 0] - view.frame_t)))
        path_ax.plot(x[here], y[here], "o", color="C3", label="at the frame")
        path_ax.legend(loc="best")
        half = max(np.ptp(x), np.ptp(y), 2.0) / 2 + 0.5  # a straight run keeps a readable square
        centre = ((x.max() + x.min()) / 2, (y.max() + y.min()) / 2)
        path_ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half))
    path_ax.set(title="top-down path", xlabel="x (m)", ylabel="y (m)", aspect="equal")
    path_ax.grid(alpha=0.3)
    fig.suptitle(title)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()
