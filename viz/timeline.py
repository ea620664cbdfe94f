"""When each trajectory node is shown in the Meshcat animation (frame numbers at a fixed fps).

Node t is reached at frame `node_frame(t) = t * substeps * per_sub`; between two
nodes the arm is key-framed `substeps` times (linear in q), `per_sub` frames apart.
Everything animated with the arm (its needle, the moving camera) uses the same clock.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Timeline:
    """Frame numbers of the trajectory nodes: `seconds_per_step` [s] per step at `fps`."""

    seconds_per_step: float = 0.5
    fps: int = 30
    substeps: int = 4

    @property
    def per_sub(self) -> int:
        """Frames between two key frames of the arm (at least 1)."""
        return max(1, int(round(self.seconds_per_step * self.fps / self.substeps)))

    def node_frame(self, t: int) -> int:
        """Frame at which node t is reached."""
        return t * self.substeps * self.per_sub

    def sub_frames(self, t: int) -> list[tuple[int, float]]:
        """(frame, fraction of the step t-1 -> t) of the key frames that lead to node t (t >= 1)."""
        base = self.node_frame(t - 1)
        return [(base + k * self.per_sub, k / self.substeps) for k in range(1, self.substeps + 1)]
