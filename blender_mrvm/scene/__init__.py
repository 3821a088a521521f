"""The Blender side of the core (imports bpy): cameras, objects, render passes, image planes."""
