"""Regenerate the committed default face: ``python -m core.default_face [--out PATH]``."""

import argparse
import time

from core.default_face import FaceParameters, generate_face, save_default_face


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", help="NPZ path (default: resources/default_face/default_face.npz)")
    args = parser.parse_args()
    start = time.perf_counter()
    front = generate_face(FaceParameters(), full_head=False)
    head = generate_face(FaceParameters())
    path = save_default_face(front, args.out, head=head)
    print(f"{head} (front: {front}) -> {path} in {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
