"""The Foxglove layout shipped with baromap (``layouts/live-view.json``), made with the SDK's
layout API so every key is one the app knows.

A 3D panel in ``map`` following the robot (the scan, the robot's frames, the live grid and
path), a plot of pressure, the floor state, and the daemon's diagnostics. The topics are the
recording's too (the live map's aside), so the same layout opens a recording, with the
post-run maps of ``maps.mcap`` beside it.
"""

from __future__ import annotations

import foxglove.layouts as fl

from baromap.liveview.channels import LIVE_MAP, LIVE_MAP_INFO, LIVE_PATH
from baromap.recording import topics


def live_layout() -> fl.Layout:
    scene = fl.ThreeDeePanel(
        title="robot on the live map",
        config=fl.ThreeDeeConfig(
            follow_tf=topics.BASE_FRAME,
            fixed_frame=topics.MAP_FRAME,
            follow_mode="follow-position",
            camera_state=fl.ThreeDeeCameraState(distance=25.0, perspective=False, phi=0.0),
            topics={
                topics.SCAN: fl.BaseRendererLaserScanTopicSettings(
                    visible=True, point_size=4.0, color_mode="flat", flat_color="#ff4040"
                ),
                LIVE_MAP: fl.BaseRendererGridTopicSettings(
                    visible=True,
                    color_mode="gradient",
                    color_field="occupancy",
                    gradient=("#ffffffff", "#000000ff"),
                    min_value=0.0,
                    max_value=100.0,
                    draw_behind=True,
                ),
                LIVE_PATH: fl.BaseRendererPosesTopicSettings(
                    visible=True, type="line", line_width=0.05, gradient=("#2080ff", "#20c0ff")
                ),
            },
        ),
    )
    pressure = fl.PlotPanel(
        title="pressure",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(value=f"{topics.BARO}.pressure_pa", timestamp_method="receiveTime")
            ],
            show_legend=True,
        ),
    )
    floor = fl.RawMessagesPanel(
        title="floor",
        config=fl.RawMessagesConfig(topic_path=topics.FLOOR_STATE, default_expanded=True),
    )
    live_map = fl.RawMessagesPanel(
        title="live map",
        config=fl.RawMessagesConfig(topic_path=LIVE_MAP_INFO, default_expanded=True),
    )
    diagnostics = fl.TablePanel(
        title="diagnostics", config=fl.TableConfig(topic_path=topics.DIAGNOSTICS)
    )
    side = fl.SplitContainer(
        direction="column",
        items=[
            fl.SplitItem(content=pressure),
            fl.SplitItem(content=floor),
            fl.SplitItem(content=live_map),
            fl.SplitItem(content=diagnostics),
        ],
    )
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[fl.SplitItem(proportion=2, content=scene), fl.SplitItem(content=side)],
        )
    )


def live_layout_json() -> str:
    """The layout as the file holds it (indented, one key a line, for readable diffs)."""
    import json

    return json.dumps(json.loads(live_layout().to_json()), indent=2) + "\n"
