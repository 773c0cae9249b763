"""Old home of the window's file/project commands; they live in `carapost.commands.file`.

Kept as a re-export while the window still imports from here (to be deleted).
"""

from carapost.commands.file import (
    ApplyCalibration,
    CreateStickMesh,
    RelocateFiles,
    RenameLabel,
)

#: The window's old name for Relocate Files (it now checks the image size too).
RelocateVideos = RelocateFiles

__all__ = ["ApplyCalibration", "CreateStickMesh", "RelocateFiles", "RelocateVideos",
           "RenameLabel"]
