"""The MuJoCo stand-in: scenes, RGB-D cameras with sensor noise, the simulated arm and grippers.

`sim` uses `prompose_grasp`; the library never imports `sim`. It arrives with issue 4.
"""
