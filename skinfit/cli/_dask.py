"""``skinfit fit-image --dask ADDRESS``: the images of a batch as tasks on an existing Dask cluster.

Each image is one task (``fit_outputs.fit_image_to_folder``); workers write their outputs into the shared
output folder, the maps EXR last, so an interrupted batch keeps every finished image and a rerun
skips them. Needs ``dask.distributed`` (``pip install "skinfit[dask]"``).
"""

from __future__ import annotations

from pathlib import Path

from .._validate import SkinfitInputError
from ._batch import fit_image_to_folder


def fit_images_on_cluster(address: str, inputs, out: Path, options: dict, *, overwrite: bool = False) -> int:
    """Submit every unfinished image to the scheduler at ``address``; print each summary as it
    finishes. Returns 0, or 1 if any image failed (its error printed, the others kept)."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise SkinfitInputError('--dask needs dask.distributed: pip install "skinfit[dask]"') from None
    todo = []
    for path in inputs:
        maps_path = Path(out) / f"{Path(path).stem}_maps.exr"
        if maps_path.exists() and not overwrite:
            print(f"{path}: {maps_path} exists, skipped (--overwrite to refit)")
        else:
            todo.append(str(Path(path).resolve()))
    if not todo:
        return 0
    options = dict(options, progress=False)  # workers have no terminal
    try:
        client = Client(address, timeout="20s")
    except OSError as err:
        raise SkinfitInputError(f"cannot reach the Dask scheduler at {address}: {err}") from None
    failed = 0
    with client:
        futures = client.map(fit_image_to_folder, todo, out=Path(out).resolve(), options=options, pure=False)
        for future in as_completed(futures):
            try:
                print(future.result())
            except Exception as err:  # one bad image must not lose the batch
                failed += 1
                print(f"skinfit fit-image: error: {err}")
    return 1 if failed else 0
