"""GPNR: generalizable patch-based neural rendering (Suhail et al., ECCV 2022), in torch (bpy-free)."""
