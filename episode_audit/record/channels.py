"""A stream's two channels in its evidence file, and its blocks written to them.

:class:`StreamChannels` registers a stream's ``steps`` and ``resets`` channels (their Arrow
schemas from the stream's space codecs) and writes a counted :class:`~.block.Block` to them as
one record batch each (:func:`~.block.step_batch`, :func:`~.block.reset_batch`).
"""

from __future__ import annotations

from typing import Any

import pyarrow as pa

from ..format import names as fmt
from ..format.schemas import reset_schema, step_schema
from ..format.spaces import SpaceCodec
from .block import Block, reset_batch, step_batch
from .counting import Compiled
from .writer import EvidenceWriter

__all__ = ["StreamChannels"]


class StreamChannels:
    """The ``steps`` and ``resets`` channels of one stream (agent, sub-env) in a file.

    Reset rows of a multi-stream file also say whose they are (``agent``) and, with games,
    which game; ``state`` adds the reset rows' snapshot column.
    """

    __slots__ = (
        "_agent",
        "_env_index",
        "_multi",
        "_reset_schema",
        "_step_schema",
        "resets",
        "steps",
    )

    def __init__(
        self,
        writer: EvidenceWriter,
        obs_codec: SpaceCodec,
        act_codec: SpaceCodec,
        *,
        env_index: int,
        agent: str | None,
        multi: bool,
        state: bool,
    ) -> None:
        self._env_index = env_index
        self._agent = agent
        self._multi = multi
        self._step_schema = step_schema(
            act_codec.field(fmt.COL_ACTION), obs_codec.field(fmt.COL_OBSERVATION)
        )
        self._reset_schema = reset_schema(
            obs_codec.field(fmt.COL_OBSERVATION), multi_stream=multi, state=state
        )
        meta = {"agent": agent or "", "env_index": str(env_index)}
        try:
            self.steps = writer.register_arrow_channel(
                fmt.TOPIC_STEPS, fmt.SCHEMA_STEP_BLOCK, self._step_schema, meta
            )
            """The steps channel's id."""
            self.resets = writer.register_arrow_channel(
                fmt.TOPIC_RESETS, fmt.SCHEMA_RESET_BLOCK, self._reset_schema, meta
            )
            """The resets channel's id."""
        except BaseException:
            writer.abandon()
            raise

    def write(
        self,
        writer: EvidenceWriter,
        block: Block,
        counted: tuple[Any, Any, pa.Array] | None,
        wall_offset: int,
        compiled: Compiled | None = None,
    ) -> None:
        """Write ``block``'s step rows and its reset rows, each as one record batch.

        ``counted`` is the block's :func:`~.block.count_block` (``None``: it has no step rows);
        ``compiled`` the compiled part that made it, if any.
        """
        if counted is not None:
            batch, last = step_batch(block, counted, self._step_schema, wall_offset, compiled)
            writer.write_batch(self.steps, batch, last)
        if block.resets:
            batch, last = reset_batch(
                block, self._reset_schema, wall_offset, self._env_index, self._agent, self._multi
            )
            writer.write_batch(self.resets, batch, last)
