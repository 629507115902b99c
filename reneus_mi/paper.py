"""The paper's fixed values (ReNeuS, Sec. 3-4), a leaf every layer may read.

Each is the default of a setting written elsewhere once (``RenderConfig.gamma`` and
``max_depth``, a scene's container IOR and ambient light), and the value synthetic data are
rendered with.
"""

#: D_re, the interface events a camera ray's tree follows.
D_RE = 2
#: The camera response: a photograph holds C^(1/GAMMA) of the linear radiance C.
GAMMA = 2.2
#: The glass: the IOR of a container whose data state none (and of synthetic data).
IOR = 1.45
#: The ambient radiance C_out (linear, every channel).
AMBIENT = 0.8
