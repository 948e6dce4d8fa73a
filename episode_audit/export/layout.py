"""The Foxglove layout for exported evidence (``docs/foxglove-layout.json``).

Built with ``foxglove.layouts``: reward and reward-term plots, episode boundaries as state
transitions, the camera image and the ending log. Regenerate the docs copy with
``python -m episode_audit.export.layout > docs/foxglove-layout.json``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Final

from ._output import missing

__all__ = ["REFERENCE_TERMS", "foxglove_layout"]

REFERENCE_TERMS: Final = (
    "shaping",
    "progress_velocity",
    "ctrl_cost",
    "failure_penalty",
    "success_bonus",
)
"""The reward terms of the reference tasks (``episode_audit.tasks``, both reward modes)."""


def foxglove_layout(
    terms: Sequence[str] = REFERENCE_TERMS,
    *,
    prefix: str = "",
    image_topic: str = "/camera/observation",
) -> str:
    """The layout as JSON for Foxglove's "Import from file…", for one stream's topics.

    ``prefix`` is the stream's topic prefix (``"/env_0"``, ``"/player_1"``; empty for
    single-env files); ``terms`` the reward terms to plot, one series each.
    """
    try:
        import foxglove.layouts as fl
    except ImportError:
        raise missing("foxglove-sdk", "foxglove") from None
    steps = f"{prefix}/steps"
    reward = fl.PlotPanel(
        title="reward",
        config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"{steps}.reward", label="reward")], show_legend=True
        ),
    )
    term_plot = fl.PlotPanel(
        title="reward terms",
        config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"{steps}.terms.{t}", label=t) for t in terms],
            show_legend=True,
        ),
    )
    boundaries = fl.StateTransitionsPanel(
        title="episodes and endings",
        config=fl.StateTransitionsConfig(
            paths=[
                fl.StateTransitionsSeries(value=f"{steps}.episode", label="episode"),
                fl.StateTransitionsSeries(value=f"{steps}.terminated", label="terminated"),
                fl.StateTransitionsSeries(value=f"{steps}.truncated", label="truncated"),
            ]
        ),
    )
    image = fl.ImagePanel(
        title="camera",
        config=fl.ImageConfig(image_mode=fl.ImageModeConfig(image_topic=image_topic)),
    )
    log = fl.LogPanel(title="endings", config=fl.LogConfig(topic_to_render="/log"))

    def column(*panels: fl.BasePanel, sizes: Sequence[float]) -> fl.SplitContainer:
        return fl.SplitContainer(
            direction="column",
            items=[
                fl.SplitItem(proportion=s, content=p) for p, s in zip(panels, sizes, strict=True)
            ],
        )

    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(
                    proportion=2, content=column(reward, term_plot, boundaries, sizes=(2, 2, 1))
                ),
                fl.SplitItem(proportion=1, content=column(image, log, sizes=(1, 1))),
            ],
        )
    )
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"


if __name__ == "__main__":
    print(foxglove_layout(), end="")
