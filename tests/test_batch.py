"""How `signpose.app.batch` cuts a run of images into chunks for its workers."""

from pathlib import Path

from signpose.app.batch import recognize_all
from signpose.pipeline.evaluate import Outcome
from signpose.pipeline.library import load_library
from signpose.pipeline.settings import preset

SCENES = Path(__file__).parents[1] / "sample_images" / "scenes"


class RecordingRunner:
    """Runs no pipeline: answers each image of a chunk with an outcome naming it, and keeps the chunks' sizes."""

    slots = 2

    def __init__(self) -> None:
        self.sizes: list[int] = []

    def share(self, value):
        return value

    def run(self, function, shared, chunks):
        for chunk in chunks:
            self.sizes.append(chunk.size)
            yield chunk, [[Outcome(error=item.name)] for item in chunk.work]

    def retried(self):
        return []

    def close(self):
        pass


def test_the_last_chunks_shrink_so_that_the_workers_finish_together():
    """40 images, chunks of at most 8, on two workers: full chunks while much is left, then smaller ones down
    to a single image, so no worker runs a full last chunk while the other waits; every image answered once,
    in its place."""
    names = [str(p) for p in sorted(SCENES.glob("scene_*.jpg"))]
    jobs = [(names[i % len(names)], None) for i in range(40)]
    runner = RecordingRunner()
    outcomes, tally = recognize_all(jobs, load_library(), [preset("default")], None, runner=runner, store=None,
                                    context={}, shared_paths=False, images_per_chunk=8, done=lambda n: None)
    assert runner.sizes[:2] == [8, 8] and runner.sizes[-1] == 1, runner.sizes
    assert runner.sizes == sorted(runner.sizes, reverse=True) and sum(runner.sizes) == 40, runner.sizes
    assert [o.error for o in outcomes[0]] == [name for name, _ in jobs] and tally.computed == 40
