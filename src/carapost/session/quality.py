"""Session actions on the quality of the tracked points (Remove Spurious Points)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from carapost.commands.stack import Command, CommandError

if TYPE_CHECKING:
    from carapost.algorithms.spurious import SpuriousParameters
    from carapost.commands.stack import CommandStack
    from carapost.model.project import Project

__all__ = ["QualityActions"]


class QualityActions:
    """Mixin of `carapost.Session`: Remove Spurious Points."""

    project: Project
    stack: CommandStack

    def spurious_points(self, params: SpuriousParameters | None = None
                        ) -> list[tuple[int, str, str]]:
        """``(point id, label, reason)`` of the face points that are not markers (nothing
        changed; see `carapost.algorithms.spurious`)."""
        from carapost.commands.quality import spurious_points

        return spurious_points(self.project, params)

    def remove_spurious_points(self, params: SpuriousParameters | None = None,
                               *, quiet: bool = False) -> Command | None:
        """Delete the face points that are not markers, one undo entry; the command's
        ``removed`` lists ``(label, reason)``. With nothing to remove: refused
        (``CommandError``), or None when ``quiet``."""
        from carapost.commands.quality import RemoveSpuriousPoints

        try:
            cmd = RemoveSpuriousPoints(self.project, params)
        except CommandError:
            if quiet:
                return None
            raise
        return self.stack.push(cmd)
