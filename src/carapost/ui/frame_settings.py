"""The frame-access settings in the Properties pane: image cache size, playback proxies.

User settings of this computer (QSettings, `carapost.ui.settings`), not project
properties: changing them is not a History entry. The cache size applies to the next
take opened.
"""

from __future__ import annotations

from PySide6.QtWidgets import QCheckBox, QSpinBox, QTreeWidget, QTreeWidgetItem

from carapost.ui.context import ActionContext
from carapost.ui.settings import (
    FRAME_CACHE_RANGE,
    build_proxies,
    frame_cache_mb,
    set_build_proxies,
    set_frame_cache_mb,
)

TITLE = "Frames (this computer)"


def add_frame_settings(tree: QTreeWidget, ctx: ActionContext) -> dict[str, object]:
    """Add the group to a properties tree; returns its editors by settings name."""
    top = QTreeWidgetItem([TITLE])
    top.setFirstColumnSpanned(True)
    top.setToolTip(0, "Kept for you on this computer (not saved in the project).")
    tree.addTopLevelItem(top)
    settings = ctx.settings

    cache = QSpinBox()
    lo, hi = FRAME_CACHE_RANGE
    cache.setRange(int(lo), int(hi))
    cache.setSingleStep(250)
    cache.setValue(int(frame_cache_mb(settings)))
    cache.valueChanged.connect(lambda v: set_frame_cache_mb(settings, float(v)))
    tip = ("Memory for decoded camera images (8-bit grey, shared by the views, playback "
           "and the processing that reads images). 1500 MB holds about 500 frames of "
           "four 1280x720 cameras. Applies to the next take opened. Default: 1500.")
    item = QTreeWidgetItem(["Image Cache", "", "MB"])
    item.setToolTip(0, tip)
    cache.setToolTip(tip)
    top.addChild(item)
    tree.setItemWidget(item, 1, cache)

    proxies = QCheckBox()
    proxies.setChecked(build_proxies(settings))
    proxies.toggled.connect(lambda v: set_build_proxies(settings, bool(v)))
    tip = ("Write fast-decoding copies of the camera videos in the background when a take "
           "opens, so playback runs at the take's frame rate (View > Build Playback "
           "Proxies writes them on request). Display only; deleting them loses nothing. "
           "Default: on.")
    item = QTreeWidgetItem(["Build Playback Proxies After Import", "", ""])
    item.setToolTip(0, tip)
    proxies.setToolTip(tip)
    top.addChild(item)
    tree.setItemWidget(item, 1, proxies)
    return {"cache_mb": cache, "build_proxies": proxies}
