"""Render the sample sign library: three Arabic plaques and their `library.json`.

Each sign is black DejaVu Sans Bold text, shaped right-to-left by Pillow's raqm layout, centred
on a white plaque that stays white to its edges (the segmentation finds signs as white blobs,
so a dark border would split the plaque from its text). Images are 8-bit grayscale PNGs,
800 x 320 px for a 0.60 x 0.24 m plaque.

    python tools/render_library.py [OUT_DIR]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont, features

ROOT = Path(__file__).resolve().parent.parent
OUT_DIR = ROOT / "sample_images" / "library"
FONT = Path("/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf")

WIDTH_PX, HEIGHT_PX = 800, 320
WIDTH_M, HEIGHT_M = 0.60, 0.24
MARGIN_PX = 56  # white border kept clear of ink on every side

SIGNS = [
    {"id": "security_compound", "name": "Security Compound", "text": "مجمع أمني"},
    {"id": "ministry_of_torture", "name": "Ministry of Torture", "text": "وزارة التعذيب"},
    {"id": "chief_of_security", "name": "Chief of Security", "text": "رئيس الأمن"},
]


def _font(size: int) -> ImageFont.FreeTypeFont:
    return ImageFont.truetype(str(FONT), size, layout_engine=ImageFont.Layout.RAQM)


def _ink_box(draw: ImageDraw.ImageDraw, text: str, font: ImageFont.FreeTypeFont) -> tuple[int, int, int, int]:
    return draw.textbbox((0, 0), text, font=font, direction="rtl", language="ar")


def render_sign(text: str) -> Image.Image:
    """The plaque for `text`: the largest font whose ink fits inside the margins, ink-centred. Mode "L"."""
    image = Image.new("L", (WIDTH_PX, HEIGHT_PX), 255)
    draw = ImageDraw.Draw(image)
    max_w, max_h = WIDTH_PX - 2 * MARGIN_PX, HEIGHT_PX - 2 * MARGIN_PX
    size = 300
    while size > 10:
        x0, y0, x1, y1 = _ink_box(draw, text, _font(size))
        if x1 - x0 <= max_w and y1 - y0 <= max_h:
            break
        size -= 2
    font = _font(size)
    x0, y0, x1, y1 = _ink_box(draw, text, font)
    # Centre the ink, not the font's line box: Arabic has tall ascenders and deep descenders.
    origin = ((WIDTH_PX - (x1 - x0)) / 2 - x0, (HEIGHT_PX - (y1 - y0)) / 2 - y0)
    draw.text(origin, text, fill=0, font=font, direction="rtl", language="ar")
    return image


def main(out_dir: Path = OUT_DIR, signs: list[dict[str, str]] = SIGNS,
         size_m: tuple[float, float] = (WIDTH_M, HEIGHT_M)) -> None:
    """Render `signs` (id, name, text) and their library.json into `out_dir`, as plaques `size_m`
    (width, height) metres."""
    if not features.check("raqm"):
        sys.exit("Pillow was built without raqm: Arabic would render as unjoined, left-to-right letters")
    out_dir.mkdir(parents=True, exist_ok=True)
    entries = []
    for sign in signs:
        image_file = f"{sign['id']}.png"
        render_sign(sign["text"]).save(out_dir / image_file, optimize=True)
        entries.append({**sign, "image": image_file, "width_m": size_m[0], "height_m": size_m[1],
                        "kind": "plaque"})
    (out_dir / "library.json").write_text(
        json.dumps({"signs": entries}, ensure_ascii=False, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {len(entries)} signs to {out_dir}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else OUT_DIR)
