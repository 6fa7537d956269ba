"""The bookkeeping the real-size stand-in scripts share (yolo_world_s_like.py,
clip_vit_b32_like.py): a graph's nodes and initialisers under construction, unique names, and a
count of multiply-accumulates."""
import numpy as np
from onnx import numpy_helper


class Graph:
    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.nodes, self.inits = [], []
        self.counter = 0
        self.macs = [0]

    def name(self, prefix):
        """A node or tensor name not used before: `prefix_N`."""
        self.counter += 1
        return f"{prefix}_{self.counter}"

    def const(self, array, prefix="c"):
        """Adds `array` as an initialiser; returns its name."""
        n = self.name(prefix)
        self.inits.append(numpy_helper.from_array(np.asarray(array), n))
        return n
