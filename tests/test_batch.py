"""How `signpose.app.batch` cuts a run of images into chunks for its workers."""

from pathlib import Path

from signpose.app.batch import recognize_all, source_files, track_all
from signpose.pipeline.evaluate import Outcome
from signpose.pipeline.settings import preset

SCENES = Path(__file__).parents[1] / "sample_images" / "scenes"
FLIGHT = Path(__file__).parents[1] / "sample_images" / "flights" / "corridor" / "flight.mp4"


class RecordingRunner:
    """Runs no pipeline: answers each image of a chunk with an outcome naming it, and keeps the chunks' sizes."""

    slots = 2

    def __init__(self) -> None:
        self.sizes: list[int] = []
        self.shared: list = []
        self.work: list = []

    def share(self, value):
        self.shared.append(value)
        return f"shared value {len(self.shared) - 1}"

    def run(self, function, shared, chunks):
        for chunk in chunks:
            self.sizes.append(chunk.size)
            self.work.append(chunk.work)
            if isinstance(chunk.work, list):
                yield chunk, [[Outcome(error=item.name)] for item in chunk.work]
            else:
                yield chunk, {"records": [], "error": None}

    def retried(self):
        return []

    def close(self):
        pass


def test_the_last_chunks_shrink_so_that_the_workers_finish_together(library):
    """40 images, chunks of at most 8, on two workers: full chunks while much is left, then smaller ones down
    to a single image, so no worker runs a full last chunk while the other waits; every image answered once,
    in its place."""
    names = [str(p) for p in sorted(SCENES.glob("scene_*.jpg"))]
    jobs = [(names[i % len(names)], None) for i in range(40)]
    runner = RecordingRunner()
    outcomes, tally = recognize_all(jobs, library, [preset("default")], None, runner=runner, store=None,
                                    context={}, shared_paths=False, images_per_chunk=8, done=lambda n: None)
    assert runner.sizes[:2] == [8, 8] and runner.sizes[-1] == 1, runner.sizes
    assert runner.sizes == sorted(runner.sizes, reverse=True) and sum(runner.sizes) == 40, runner.sizes
    assert [o.error for o in outcomes[0]] == [name for name, _ in jobs] and tally.computed == 40


def test_a_flight_in_ranges_is_shared_with_the_workers_once_not_sent_with_each_range(library):
    """A flight cut into 4 ranges under 2 settings variants: its file is handed to the runner to share once
    (a Dask cluster scatters it to every worker), and each of the 8 ranges names that shared copy."""
    runner = RecordingRunner()
    track_all([(str(FLIGHT), None)], library, [preset("default"), preset("paper")], sign_map=None,
              topic=None, fps=None, max_frames=120, max_pixels=10**8, frames_per_chunk=30, runner=runner, store=None,
              shared_paths=False, planned=lambda n: None, done=lambda n: None)
    assert runner.shared[1:] == [source_files(str(FLIGHT))], "the flight was not shared once, as its files"
    assert len(runner.work) == 8 and {source for _, source in runner.work} == {"shared value 1"}
