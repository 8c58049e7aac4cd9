"""Pose, twist and measurement streams over HTTP/WebSocket (the router lives in `feed.router`)."""

from servo_app.inputs.feed.models import FeedAck, FeedMessage, FeedSourceConfig, MeasurementFeed, PoseFeed, TwistFeed
from servo_app.inputs.feed.registry import (
    FeedRegistry,
    FeedRejected,
    FeedStats,
    FlangeLimit,
    UnknownSource,
    parse_feed_message,
)

__all__ = [
    "FeedAck", "FeedMessage", "FeedRegistry", "FeedRejected", "FeedSourceConfig", "FeedStats", "FlangeLimit",
    "MeasurementFeed", "PoseFeed", "TwistFeed", "UnknownSource", "parse_feed_message",
]
