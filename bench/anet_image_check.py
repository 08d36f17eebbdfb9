# SPDX-License-Identifier: Apache-2.0
"""
astrometry.net on the image itself (its own source extraction) at SIP orders 2-4: a check of the references.

For each image and SIP (tweak) order two `solve-field` runs, one at a time, in a temp dir:
"own" = blind on the image within the pixel-scale range (the manifest's reference x (1 -/+ margin)), no position
hint, as the manifest's references were made (at order 2); "dense" = that solution given back with `--verify`,
`--crpix-center`, `--no-verify-uniformize`, `--no-verify-dedup`: every Tycho-2 index whose quads fit the field
verifies and tweaks it, the best log-odds kept (usually a denser index, many more matches). Each WCS's line of sight
through the image centre pixel is compared with our `solve` and with the manifest's reference; so is a `.repo.wcs`
beside the image. Needs the Debian packages astrometry.net and astrometry-data-tycho2-10-19 (not a dependency of the
project). Our spots are not used: independent of our centroider.

    python -m bench.anet_image_check gran_polar_05sec unh_DSC_0104 --orders 2 3 4 --cpulimit 120 --scale-margin 0.1
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench import bench_realdata as bench  # noqa: E402
from bench.anet_spot_check import _arcsec, wcs_centre  # noqa: E402

STAGES = ("own", "dense")


def unit(ra_deg: float, dec_deg: float) -> np.ndarray:
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.array([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)])


def solve_field(image: Path, scale_arcsec: tuple[float, float], order: int, cpulimit_s: int, work: Path,
                extra: list[str]) -> dict:
    """Run solve-field on `image` in `work`; return its WCS path (None if unsolved), matches, index id, SIP order."""
    subprocess.run(["solve-field", "--overwrite", "--no-plots", "--new-fits", "none", "--scale-units", "arcsecperpix",
                    "--scale-low", f"{scale_arcsec[0]:.2f}", "--scale-high", f"{scale_arcsec[1]:.2f}",
                    "--cpulimit", str(cpulimit_s), "--tweak-order", str(order), "--temp-dir", str(work),
                    "--dir", str(work), *extra, str(image)], capture_output=True, text=True)
    from astropy.io import fits

    wcs, corr = work / (image.stem + ".wcs"), work / (image.stem + ".corr")
    if not wcs.exists():
        return {"wcs": None}
    header = fits.getheader(wcs)
    index = next((c.split(":")[1].strip() for c in header.get("COMMENT", []) if c.startswith("index id:")), "?")
    return {"wcs": wcs, "matches": len(fits.getdata(corr, 1)), "index": index, "sip_order": header.get("A_ORDER")}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("images", nargs="+", help="corpus image ids")
    parser.add_argument("--orders", nargs="+", type=int, default=[2, 3, 4], help="SIP (tweak) orders")
    parser.add_argument("--cpulimit", type=int, default=120, help="per solve-field run [CPU s]")
    parser.add_argument("--scale-margin", type=float, default=0.10,
                        help="scale range = the reference's pixel scale x (1 -/+ this)")
    args = parser.parse_args(argv)
    if shutil.which("solve-field") is None:
        print("solve-field not found: apt-get install astrometry.net astrometry-data-tycho2-10-19", file=sys.stderr)
        return 2
    corpus = bench.find_corpus()
    entries = {e["id"]: e for e in json.loads((corpus / "MANIFEST.json").read_text())["images"]}
    rows, notes = [], []
    for image in bench.load_corpus(corpus, args.images):
        code, ours, _, _ = bench.run_solve_command(bench.solve_argv(image))
        ours_xyz = unit(ours["ra_deg"], ours["dec_deg"]) if code == 0 else None
        ref_xyz = image.reference[:, 2] if image.reference is not None else None
        scale_arcsec = entries[image.id]["reference"]["pixel_scale_arcsec_at_centre"]
        scale_range = (scale_arcsec * (1 - args.scale_margin), scale_arcsec * (1 + args.scale_margin))

        def apart(wcs: Path) -> tuple[np.ndarray, str, str]:
            """Return the centre pixel's line of sight through `wcs`, its distances from ours, the reference [″]."""
            centre = wcs_centre(wcs, image.width, image.height)
            return centre, *(f"{_arcsec(centre, xyz):.0f}" if xyz is not None else "–" for xyz in (ours_xyz, ref_xyz))

        repo_wcs = image.path.with_name(image.path.name + ".repo.wcs")
        if repo_wcs.exists():
            _, from_ours, from_ref = apart(repo_wcs)
            notes.append(f"{image.id}: {repo_wcs.name} centre {from_ours}\" from ours, {from_ref}\" from reference")
            print(notes[-1], flush=True)
        cells, centres_of = {stage: [] for stage in STAGES}, {stage: [] for stage in STAGES}
        for order in args.orders:
            with tempfile.TemporaryDirectory() as tmp:
                own_dir, dense_dir = Path(tmp, "own"), Path(tmp, "dense")
                own_dir.mkdir(), dense_dir.mkdir()
                own = solve_field(image.path, scale_range, order, args.cpulimit, own_dir, [])
                dense = (solve_field(image.path, scale_range, order, args.cpulimit, dense_dir,
                                     ["--crpix-center", "--no-verify-uniformize", "--no-verify-dedup",
                                      "--verify", str(own["wcs"])]) if own["wcs"] else {"wcs": None})
                for stage, run in zip(STAGES, (own, dense)):
                    if run["wcs"] is None:
                        cells[stage] += ["not solved", "–", "–"]
                        print(f"{image.id} SIP {order} {stage}: not solved", flush=True)
                        continue
                    sip = f"SIP {run['sip_order']}" if run["sip_order"] else "TAN only"
                    centre, from_ours, from_ref = apart(run["wcs"])
                    centres_of[stage].append(centre)
                    cells[stage] += [f"{run['matches']} ({run['index']}, {sip})", from_ours, from_ref]
                    print(f"{image.id} SIP {order} {stage}: {run['matches']} matches (index {run['index']}, {sip}); "
                          f"centre {from_ours}\" from ours, {from_ref}\" from reference", flush=True)
        for stage in STAGES:  # spread: the largest angle between two orders' image centres
            spread_arcsec = max((_arcsec(a, b) for a in centres_of[stage] for b in centres_of[stage]), default=None)
            rows.append([image.id, f"{image.fov_h_deg:.1f}", stage, *cells[stage],
                         f"{spread_arcsec:.0f}" if spread_arcsec is not None else "–"])
    head = ["image", "field °", "run"] + [f"SIP {o}: {c}" for o in args.orders
                                          for c in ("matches (index, WCS)", "from ours ″", "from reference ″")]
    head.append("spread between orders ″")
    print("\n| " + " | ".join(head) + " |\n|" + "---|" * 3 + "---:|" * (len(head) - 3))
    print("\n".join("| " + " | ".join(row) + " |" for row in rows))
    print("\n" + "\n".join(f"- {note}" for note in notes))
    return 0


if __name__ == "__main__":
    sys.exit(main())
