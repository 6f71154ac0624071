"""AFHQ animal faces: ``<root>/{train,val}/{cat,dog,wild}/*.png``; grey -> density, uniform chroma."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from data_gen.makers.base import SourceError, find_images
from data_gen.makers.folder import FolderMaker


class AnimalsMaker(FolderMaker):
    """AFHQ images of the chosen splits and classes, sorted by split, class and file name."""

    name = "animals"
    layout = "AFHQ: <root>/train|val/cat|dog|wild/*.png"

    def __init__(
        self,
        size: int,
        root: str | None = None,
        splits: Sequence[str] = ("train", "val"),
        classes: Sequence[str] = ("cat", "dog", "wild"),
        palette: str | None = None,
    ) -> None:
        self.splits, self.classes = list(splits), list(classes)
        super().__init__(size, root, gaussian_fraction=0.0, palette=palette)

    def list_images(self, root: Path) -> list[Path]:
        folders = [root / split / kind for split in self.splits for kind in self.classes]
        if not any(folder.is_dir() for folder in folders):
            raise SourceError(f"dataset animals: none of {', '.join(f'{s}/{c}' for s in self.splits for c in self.classes)} "
                              f"exists under {root} ({self.layout})")
        return [path for folder in folders if folder.is_dir() for path in find_images(folder)]
