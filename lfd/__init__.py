"""lfd: learning manipulation tasks from demonstrations with learned virtual landmarks.

Implements Bowen & Alterovitz, "Asymptotically Optimal Motion Planning for Tasks
Using Learned Virtual Landmarks". The package depends on torch, numpy and networkx
only; everything that touches a simulator lives in the separate ``sim`` package.
"""

__version__ = "0.1.0"
