"""Gymnasium spaces <-> Arrow columns: the one encode/decode pair of episode-audit.

- :func:`codec_for` picks the :class:`SpaceCodec` of a space.
- :class:`SpaceCodec` knows the Arrow type of a space, decodes columns back to native values and
  checks them (``contains``) and compares them (``compare``) a whole column at a time.
- :class:`ColumnBuffer` collects one value per step (the recorder's hot path) and turns them into
  one Arrow array.
- :func:`describe_space` / :func:`space_from_description` write a space as JSON and read it back.

How each space is stored: ``docs/format.md``, "Space → Arrow".

Example:
>>> import numpy as np
>>> from gymnasium import spaces
>>> codec = codec_for(spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32))
>>> codec.arrow_type
FixedSizeListType(fixed_size_list<item: float>[2])
>>> buffer = codec.new_buffer()
>>> buffer.append(np.array([0.5, -0.5], dtype=np.float32)) is None
True
>>> buffer.append(np.array([2.0, 0.0]))
'dtype float64 cast to float32'
>>> array = buffer.finish()
>>> codec.decode(array)
[array([ 0.5, -0.5], dtype=float32), array([2., 0.], dtype=float32)]
>>> codec.contains(array)
array([ True, False])
"""

from .buffers import ColumnBuffer
from .codecs import SpaceCodec, codec_for, codec_in, equal_elements
from .descriptions import UnknownSpace, describe_space, space_from_description, unknown_spaces

__all__ = [
    "ColumnBuffer",
    "SpaceCodec",
    "UnknownSpace",
    "codec_for",
    "codec_in",
    "describe_space",
    "equal_elements",
    "space_from_description",
    "unknown_spaces",
]
