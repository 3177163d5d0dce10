"""The options model of a name that takes none (``link-reboot``, ``operator``, the ``sqlite`` and ``sql`` stores).

Why a model for nothing: a name registered without one takes any mapping unread, so a station file's
``options:`` under it — a store's ``path`` written there instead of on the entry — passed ``magline check``
and was silently ignored; with it, each such key is an error with file and line.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class NoOptions(BaseModel):
    """No options: every key under this name's ``options`` is an error."""

    model_config = ConfigDict(extra="forbid", strict=True, defer_build=True)
