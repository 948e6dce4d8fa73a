"""Each sub-env's info from a vector step's or reset's info, as the sub-env would give it.

:func:`env_infos` reads Gymnasium's vector dict form (``info[k][i]`` where ``info["_k"][i]``;
nested dicts alike; a key without a mask is a guess, noted ``info_unmasked``) or a list of
per-sub-env infos (``DictInfoToList``); see ``docs/format.md``, "Vector files".
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ..notes import note

__all__ = ["EMPTY", "env_infos", "split_info"]

EMPTY: dict[str, Any] = {}
"""The info of a sub-env a vector info says nothing about (shared: never written to)."""


def _entries(value: Any, n: int) -> Any:
    """``value`` itself if it holds one entry per sub-env (an array, a list or a tuple of n)."""
    if isinstance(value, np.ndarray):
        return value if value.ndim and len(value) == n else None
    if isinstance(value, (list, tuple)) and len(value) == n:
        return value
    return None


def split_info(
    infos: Mapping[Any, Any], n: int, prefix: str = "", inherited: Any = None
) -> tuple[list[dict[Any, Any]], list[str]]:
    """Each sub-env's info from a vector info dict, and the keys read without a mask.

    A key ``k`` with a mask ``_k`` (Gymnasium's vector envs give every key one): ``infos[k][i]``
    where ``infos["_k"][i]`` is set. A key without one (a vector env of one's own may leave them
    out) is taken as present for every sub-env: a value of ``n`` entries (an array, a list or a
    tuple) as each sub-env's own entry, any other value as the same for every sub-env. Such keys
    are returned (dotted within nested dicts, which are read the same way) so that the rows they
    reached can say so: that reading is a guess. Within a nested dict whose own key has a mask
    (Gymnasium's vector ``RecordEpisodeStatistics``: ``_episode``, not ``episode._r``), a key
    without one takes that mask (``inherited``): no guess.
    """
    outs: list[dict[Any, Any]] = [{} for _ in range(n)]
    guessed: list[str] = []
    for key, value in infos.items():
        mask = infos.get(f"_{key}")
        present = None if mask is None else _entries(mask, n)
        if present is None and type(key) is str and key[:1] == "_" and key[1:] in infos:
            continue  # the mask of another key
        if mask is None and inherited is not None:
            present = inherited  # (the enclosing key's mask)
        if isinstance(value, Mapping):
            values, inner = split_info(value, n, f"{prefix}{key}.", present)
            guessed += inner
        else:
            values = _entries(value, n)
            if values is None:  # not one entry per sub-env (masked or not)
                values = [value] * n
                guessed.append(f"{prefix}{key} (the same for every sub-env)")
            elif present is None:
                guessed.append(f"{prefix}{key}")
        if present is None:
            if mask is not None:  # a mask that is not one truth value per sub-env
                guessed.append(f"{prefix}_{key} (not a mask of {n})")
            if isinstance(value, Mapping):
                for out, sub in zip(outs, values, strict=True):
                    if sub:
                        out[key] = sub
            else:
                for i, out in enumerate(outs):
                    out[key] = values[i]
            continue
        if isinstance(present, np.ndarray):
            present = present.tolist()
        for i, here in enumerate(present):
            if here:
                outs[i][key] = values[i]
    return outs, guessed


def env_infos(infos: Any, n: int) -> tuple[list[Any], str | None]:
    """Each sub-env's info from a vector step's or reset's info, as the sub-env would give it.

    The vector dict form (:func:`split_info`), or a list of per-sub-env infos (what Gymnasium's
    ``DictInfoToList`` makes of it); anything else is handed on as it is (the stream notes an
    info that is not a dict). Also the ``info_unmasked`` note for every sub-env's row when the
    dict had keys without a ``_key`` mask (``None`` when it had none).
    """
    if isinstance(infos, Mapping):
        if not infos:
            return [EMPTY] * n, None
        outs, guessed = split_info(infos, n)
        if not guessed:
            return outs, None
        return outs, note(
            "info_unmasked",
            f"vector info without a '_<key>' mask of {n} truth values for {', '.join(guessed)}: "
            f"taken as present for every sub-env, a value of {n} entries as one entry each",
        )
    if isinstance(infos, (list, tuple)) and len(infos) == n:
        return list(infos), None
    return [infos] * n, None
