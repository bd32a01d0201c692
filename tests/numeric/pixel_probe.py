"""Run as a script: render 60 camera frames at random poses, detect the pad in each, and print
the hashes of the images and of the detections (one JSON line). Run under two numeric
environments, equal hashes mean the same pixels and the same detections."""

import hashlib
import json

import numpy as np

from companion.vision.perception import PadDetector
from sitl.camera import CameraRenderer
from sitl.config import SitlConfig
from sitl.world import World

cfg = SitlConfig()
r = CameraRenderer(cfg.camera, World(cfg.world))
d = PadDetector()
h = hashlib.sha256()
dets = []
rng = np.random.default_rng(0)
for i in range(60):
    pos = [rng.uniform(-4, 4), rng.uniform(-4, 4), -rng.uniform(1.5, 12)]
    att = rng.uniform(-0.3, 0.3, 3)
    img = r.render(pos, att, t_s=i * 0.1)
    h.update(img.tobytes())
    det = d.detect(img)
    dets.append(None if det is None else repr(det))
print(json.dumps({"images": h.hexdigest(), "detections": hashlib.sha256(repr(dets).encode()).hexdigest(), "found": sum(x is not None for x in dets)}))
