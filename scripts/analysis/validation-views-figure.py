#!/usr/bin/env python3
"""docs/validation-views.png: the test bed's validation views (experiments/bed/README.md rule 18)
at one step: the truth, NeuroFluid as shipped (A), NeuroFluid with the refit and its replay (C),
C's renderer on the true particles, and NeRF-T on NeuroFluid's images.

    python3 scripts/analysis/validation-views-figure.py [ROOT=runs/r18/val] [STEP=25]   # needs Pillow

Reads the renders `experiments/research/bed/validation-evals.sh` leaves in ROOT/<scene>-A and
ROOT/<scene>-C (`eval/renders/<view>/t<step>.png`, `true_particles_t<step>.png`: each
[render | truth] side by side) and NeRF-T's in ROOT/<scene>-A/nerf-t/renders/<view>/.
"""

import os
import sys

from PIL import Image, ImageDraw, ImageFont

SCENES = ["water-dam-z", "water-torus-tilted-z", "honey-drop-z"]
SHORT = {"water-dam-z": "water-dam", "water-torus-tilted-z": "torus", "honey-drop-z": "honey-drop"}
VIEWS = ["view_6", "view_7"]
LABELS = ["truth", "A: as shipped", "C: refit + replay", "C on the truth", "NeRF-T"]
SCALE = 2


def halves(path):
    """(render, truth) of a [render | truth] picture."""
    im = Image.open(path).convert("RGB")
    w, h = im.size
    return im.crop((0, 0, w // 2, h)), im.crop((w // 2, 0, w, h))


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "runs/r18/val"
    t = int(sys.argv[2]) if len(sys.argv) > 2 else 25
    font = ImageFont.truetype("/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf", 12)
    rows = []
    for scene in SCENES:
        a, c = (os.path.join(root, f"{SHORT[scene]}-{k}") for k in "AC")
        for view in VIEWS:
            name = f"t{t:04}.png"
            ours_a, truth = halves(os.path.join(a, "eval", "renders", view, name))
            ours_c, _ = halves(os.path.join(c, "eval", "renders", view, name))
            on_truth, _ = halves(os.path.join(c, "eval", "renders", view, f"true_particles_{name}"))
            nerf_t, _ = halves(os.path.join(a, "nerf-t", "renders", view, name))
            panels = [p.resize((p.width * SCALE, p.height * SCALE), Image.LANCZOS)
                      for p in (truth, ours_a, ours_c, on_truth, nerf_t)]
            pw, ph = panels[0].size
            row = Image.new("RGB", (pw * len(panels), ph + 30), "white")
            draw = ImageDraw.Draw(row)
            for i, (p, label) in enumerate(zip(panels, LABELS)):
                row.paste(p, (i * pw, 15))
                draw.text((i * pw + 4, 0), label, fill=(0, 0, 0), font=font)
            draw.text((4, ph + 15), f"{scene}, {view} (validation), t = {t}, seed 10", fill=(90, 90, 90), font=font)
            rows.append(row)
    out = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows)), "white")
    y = 0
    for r in rows:
        out.paste(r, (0, y))
        y += r.height
    out.save("docs/validation-views.png")
    print("docs/validation-views.png", out.size)


if __name__ == "__main__":
    main()
