"""Render synthetic surveys (`pipeline.synth_survey`): photos of a room with signs round its walls,
their camera, the signs' library and the true map.

Without arguments, regenerates the committed sample `sample_images/surveys/room/`: six signs on
three walls, 36 photos at 640x480, its own library (the sample library's three plaques and three
more, all 1.0 x 0.4 m: a survey needs four or more signs), `signpose map build sample_images/surveys/room -o map.yaml`
builds its map. With `--out`, renders another survey:

    python tools/make_survey.py
    python tools/make_survey.py --out /tmp/survey1 --seed 1 --photos 48 --spacing 3 6
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from tqdm import tqdm

from render_library import SIGNS  # tools/ is the script's folder, first on sys.path
from render_library import main as render_library
from signpose.pipeline.library import load_library
from signpose.pipeline.synth import synthetic_camera
from signpose.pipeline.synth_survey import write_survey

SAMPLE = Path(__file__).resolve().parent.parent / "sample_images" / "surveys" / "room"
# Besides the sample library's three: texts as distinct as theirs, so that no two plaques look alike.
SURVEY_SIGNS = [
    {"id": "archives", "name": "Archives", "text": "الأرشيف"},
    {"id": "directors_office", "name": "Director's Office", "text": "مكتب المدير"},
    {"id": "emergency_exit", "name": "Emergency Exit", "text": "مخرج الطوارئ"},
]
# The survey's plaques are larger than the sample library's (1.0 x 0.4 m, as a door or corridor
# sign): seen together from across a room at 640x480, they are still 70 px or more wide.
PLAQUE_SIZE_M = (1.0, 0.4)
# JPEG quality of the committed sample: 36 photos in under 2.5 MB for a fresh clone.
SAMPLE_QUALITY = 80


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=SAMPLE, help="survey folder (default: the committed sample)")
    parser.add_argument("--photos", type=int, default=36)
    parser.add_argument("--signs", type=int, default=6, help="signs round the walls, 2 to 6")
    parser.add_argument("--spacing", type=float, nargs=2, default=(2.0, 4.0), metavar=("MIN", "MAX"),
                        help="metres between neighbouring signs along the walls")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quality", type=int, default=SAMPLE_QUALITY, help="JPEG quality")
    args = parser.parse_args()
    library_dir = args.out / "library"
    if library_dir.exists():
        shutil.rmtree(library_dir)
    render_library(library_dir, [*SIGNS, *SURVEY_SIGNS], PLAQUE_SIZE_M)
    library = load_library(library_dir)
    labels = [s.id for s in library.signs][: args.signs]
    if len(labels) < args.signs:
        sys.exit(f"the survey library has {len(labels)} signs")
    with tqdm(total=args.photos, desc=str(args.out), unit="photo") as bar:
        write_survey(args.out, library, synthetic_camera(), labels=labels, n_photos=args.photos,
                     spacing_m=tuple(args.spacing), seed=args.seed, quality=args.quality,
                     progress=lambda done, total: bar.update(done - bar.n))


if __name__ == "__main__":
    main()
