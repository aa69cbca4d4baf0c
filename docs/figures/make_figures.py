"""The README's figures: ``python docs/figures/make_figures.py`` (from the repository root; about
a minute). Each is a jaxtree plot at its own 120 dpi, stored as an 8-bit palette PNG where that keeps it small."""

import io
import pathlib

import matplotlib
from PIL import Image

import jaxtree
from jaxtree._src.io.figures import DPI

matplotlib.use("Agg")
HERE = pathlib.Path(__file__).parent


def save(fig, name):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    img = Image.open(buf).convert("RGB")
    if len(buf.getvalue()) > 150_000:  # many curves: 256 colours hold them, at a third of the size
        img = img.quantize(colors=256, method=Image.Quantize.MEDIANCUT)
    img.save(HERE / name, optimize=True, dpi=(DPI,) * 2)
    print(name, (HERE / name).stat().st_size, "bytes")


fig4 = jaxtree.load_scene("fig4")
runs = {att: jaxtree.simulate(fig4, 20.0, attitude=att, saveat=681) for att in ("euler123", "quaternion")}
save(
    jaxtree.plot_histories(runs, drift=True, title="fig4, 20 s: Euler 1-2-3 angles vs quaternions"),
    "fig4_histories.png",
)

wings = jaxtree.load_scene("wings")
sol = jaxtree.simulate(wings, 20.0, saveat=495)
save(
    jaxtree.plot_drift(sol, title="wings, 20 s: dampers take 29 % of the energy; momentum kept to round-off"),
    "wings_drift.png",
)

chain = jaxtree.load_scene("chain50")
sol = jaxtree.simulate(chain, 5.0, saveat=401)
save(jaxtree.plot_histories(sol, title="chain50, 5 s: 50 sprung hinges as a time-hinge map"), "chain50_histories.png")
