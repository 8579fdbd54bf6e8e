"""The live viser view of domains, priors and explorers (a consumer of plain snapshots)."""

from app.viewer.scene import MazeScene
from app.viewer.state import AdviceGiven, DomainView, Feed, SessionView, Snapshot
from app.viewer.viewer import Viewer

__all__ = ["AdviceGiven", "DomainView", "Feed", "MazeScene", "SessionView", "Snapshot", "Viewer"]
