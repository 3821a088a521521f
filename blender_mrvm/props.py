"""Scene-level settings the panels draw and the operators read (one PropertyGroup per feature).

Each group is attached to ``bpy.types.Scene`` under the name in ``SCENE_PROPERTIES``; operators turn
a group into the frozen dataclass config of the core function with a ``to_config`` helper.
"""

from __future__ import annotations

import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from .scene.procedural._registry import CATEGORIES
from .validation import MAX_REFERENCE_SIDE

MODEL_KINDS = [
    ("nerformer_mrvm", "NeRFormer + MRVM", "Radiance field from a transformer across views and along rays (few views, "
                                           "objects on white)"),
    ("gpnr", "GPNR", "Patch-based light-field transformer: colours from epipolar patches of the references "
                     "(shines with many nearby views)"),
]
"""The model kinds (``models/registry.py``) the panel offers."""

SHIPPED_MODELS = [
    ("auto", "Auto: by the cameras", "NeRFormer + MRVM: the default model when every camera sits on the 30-degree "
                                     "turntable it was trained on (height, field of view, framing, azimuth), else "
                                     "the any-viewpoint model on the CPU and the quality model on a GPU; GPNR for "
                                     "rooms when the references are a capture of a whole scene; the note after a "
                                     "run says which"),
] + MODEL_KINDS + [
    ("gpnr_captures", "GPNR for rooms and captures", "GPNR trained on capture-like rooms: for scenes and photo "
                                                     "captures (Recover Poses), not objects on white"),
    ("mrvm_anyview", "NeRFormer + MRVM, any viewpoint", "The default model fine-tuned on sphere-rig renders too: "
                     "for cameras above, below or nearer than the 30-degree turntable (on it the default model is "
                     "sharper)"),
    ("mrvm_quality", "NeRFormer + MRVM, quality", "The paper's NeRFormer with an ImageNet VGG16 encoder, partly "
                     "trained on a GPU: the best for cameras anywhere (on the turntable the default is sharper); "
                     "many times slower on a CPU"),
]
"""The shipped novel-view models the panel offers (``models.pretrained``: ``auto``'s choice by the cameras, one per
kind, then named models)."""
def _with_figures(items):
    """Each shipped model's tooltip ends with its measured quality and seconds per view, read from the one place
    that holds them (``models.pretrained.FIGURES``, which the panel's line under the choice shows too)."""
    from .models.pretrained import FIGURES

    return [(key, name, f"{text}. Measured: {FIGURES[key]}" if key in FIGURES else text, *rest)
            for key, name, text, *rest in items]


SHIPPED_MODELS = [(*item, number) for number, item in enumerate(_with_figures(SHIPPED_MODELS))]
# A .blend stores an enum choice as its item's number, which without one is its position: inserting "auto" first
# (8fb737e, 2026-11-27) made files saved before open on the next model up (gpnr -> nerformer_mrvm). The numbers are
# now fixed: a new model is appended with a new number, never inserted (tests/test_addon.py pins them). Files saved
# before 2026-11-27 still open one item up (the panel shows which; no file says its add-on version).

DEVICES = [
    ("AUTO", "Auto", "CUDA when available, else CPU"),
    ("CPU", "CPU", "Always the CPU"),
    ("CUDA", "CUDA", "An NVIDIA GPU"),
]
"""Where the worker runs a model."""
QUALITY_LEVELS = [
    ("FULL", "Full", "Render as the model was trained"),
    ("PREVIEW", "Preview", "Half the samples per ray: about 1.6-1.9x faster for a few tenths of a dB (a preview "
                           "of the cameras and the look before the full render)"),
]
"""Inference speed/quality levels (``models.registry.quality_overrides``), the commands' ``--quality``."""
PRECISION_CHOICES = [
    ("AUTO", "Auto", "bf16 on a GPU (every shipped model scores the same there and renders 1.04-1.21x faster); "
                     "on the CPU int8 for the wide NeRFormer models (the quality model 1.3x faster, the same "
                     "images), else fp32"),
    ("FP32", "fp32", "Full precision"),
    ("BF16", "bf16", "bfloat16 autocast: faster on a GPU; on a CPU the same images, no faster"),
    ("FP16", "fp16", "float16 autocast: a GPU only"),
    ("INT8", "int8", "int8 linear layers, the CPU only: the quality model 1.3x faster at the same images, the room "
                     "GPNR 1.2x for a little quality; the narrow default models no faster"),
]
"""Inference precision (``models.precision.SYNTH_PRECISIONS``), synthesize's ``--precision``."""
IMAGE_OUTPUTS = [
    ("FILES", "Files", "Save PNG files into the output folder and reference them"),
    ("PACK", "Pack into .blend", "Pack the images into the .blend file"),
]
"""Where image planes keep their images."""
DEVICE_TIP = "Where the model runs: an NVIDIA GPU is many times faster than the CPU"
QUALITY_TIP = "Full renders as the model was trained; Preview takes about half the time for slightly softer views"
OUTPUT_TIP = "Where the image planes' images are kept: files in the output folder, or packed into the .blend"

ENGINES = [
    ("CYCLES", "Cycles", "Path tracing on the CPU (default; all passes in one render)"),
    ("BLENDER_EEVEE", "EEVEE", "Rasterizer (slow on software GL); data passes from a 1-sample Cycles render"),
    ("BLENDER_WORKBENCH", "Workbench", "Flat viewport shading, fastest; data passes from a 1-sample Cycles render"),
]
RIGS = [
    ("sphere", "Sphere", "Uniform random directions on a sphere (seeded)"),
    ("hemisphere", "Hemisphere", "Uniform random directions on the upper hemisphere (seeded)"),
    ("spiral", "Spiral", "Archimedean spiral over the upper hemisphere (the SRN test layout)"),
    ("turntable", "Turntable", "Evenly spaced azimuths at a fixed elevation"),
    ("scene", "Scene cameras", "The cameras already in the scene"),
]


PATH_OPTIONS = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set()
"""Options of every file and folder setting: ``//`` (relative to the .blend) is meant there. Blender 4.5 and later
warn at each ``//`` value of a path property without this option; 4.2 to 4.4 have no such option."""


LIBRARY_ITEMS = [("ALL", "All 13 categories", "Every category of the procedural library")] + [
    (c, c.capitalize(), f"Procedural {c}s") for c in CATEGORIES]


class MRVM_PG_dataset(bpy.types.PropertyGroup):
    """Settings of the Render dataset operator."""

    source: EnumProperty(name="Objects", items=[
        ("SELECTED", "Selected objects", "Each selected mesh object becomes one dataset object"),
        ("PATH", "Mesh files / ShapeNet", "A mesh file, a folder of mesh files, or a ShapeNetCore folder"),
        ("LIBRARY", "Procedural library", "Generated ShapeNet-13-style objects with part labels"),
    ], default="SELECTED", description="What to render: the selected mesh objects, mesh files, or objects of the "
                                       "procedural library")
    library_category: EnumProperty(name="Category", items=LIBRARY_ITEMS, default="ALL",
                                   description="Which kind of procedural object to generate")
    library_count: IntProperty(name="Objects", default=4, min=1, soft_max=1000,
                               description="Objects (seeds) per category")
    library_seed: IntProperty(name="First seed", default=0, min=0,
                              description="Seed of the first generated object; each next object takes the next seed "
                                          "(the same seed always makes the same object)")
    source_path: StringProperty(name="Path", subtype="FILE_PATH", options=PATH_OPTIONS,
                                description="Mesh file (OBJ, PLY, STL, glTF/GLB, OFF, FBX, USD, Alembic; COLLADA, 3DS and "
                                            "others where assimp-py is installed), .blend or .zip archive of "
                                            "them, folder of them, or ShapeNetCore folder")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_dataset",
                               description="Dataset root folder (// is relative to the .blend)")
    rig: EnumProperty(name="Rig", items=RIGS, default="sphere", description="Where the cameras that render each "
                                                                           "object stand")
    views: IntProperty(name="Views", default=24, min=1, max=10000, soft_max=250,
                       description="Views per object (images rendered of each object)")
    resolution: IntProperty(name="Resolution", default=128, min=1, max=8192, subtype="PIXEL", description="Image width and height, pixels (the Scene rig: the longer side, in the scene's frame shape)")
    engine: EnumProperty(name="Engine", items=ENGINES, default="CYCLES",
                         description="Render engine of the colour images (depth, normals and masks are computed "
                                     "exactly, whatever the engine)")
    samples: IntProperty(name="Samples", default=32, min=1, soft_max=1024, description="Cycles / EEVEE samples per pixel")
    rgba: BoolProperty(name="Transparent background", default=False,
                       description="Write RGBA images instead of compositing on white")
    fov: FloatProperty(name="Field of view", default=0.6981317, min=0.01745, max=2.967, subtype="ANGLE",
                       description="Horizontal field of view of generated cameras (the distance adapts so the object fills the frame)")
    elevation: FloatProperty(name="Elevation", default=0.3490659, min=-1.5707963, max=1.5707963, subtype="ANGLE",
                             description="Camera elevation of the turntable rig")
    seed: IntProperty(name="Seed", default=0, min=0, description="Seed of random rigs and splits")
    force: BoolProperty(name="Overwrite", default=False,
                        description="Overwrite an output folder that holds another dataset")
    skip_bad_meshes: BoolProperty(name="Skip bad meshes", default=False,
                                  description="Skip a mesh file that cannot be read or is refused (no faces, NaN "
                                              "coordinates) and go on with the others, naming each at the end")
    # Status of a running job (drawn by the panel).
    running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})


# --- Capture (issue 6): settings of the Recover poses operator -------------------------------
CAPTURE_MODELS = [
    ("SIMPLE_PINHOLE", "Simple pinhole", "One focal length, no distortion (phones undistort in-camera)"),
    ("PINHOLE", "Pinhole", "Two focal lengths, no distortion"),
    ("SIMPLE_RADIAL", "Simple radial", "One focal length, one radial distortion term (images are undistorted)"),
    ("RADIAL", "Radial", "Two radial distortion terms (images are undistorted)"),
    ("OPENCV", "OpenCV", "fx, fy, k1, k2, p1, p2 (wide-angle lenses; images are undistorted)"),
]


class MRVM_PG_capture(bpy.types.PropertyGroup):
    """Settings of the Recover poses operator."""

    images_dir: StringProperty(name="Photos", subtype="FILE_PATH", options=PATH_OPTIONS,
                               description="Folder of photos or video frames, all of one size (HEIC and WebP "
                                           "too), or a video file (mp4, mov, ...)")
    video_frames: IntProperty(name="Video frames", default=40, min=3, soft_max=400,
                              description="Of a video: the sharpest frame of each of this many equal spans of it, "
                                          "a paused camera's frames counted once")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_capture",
                               description="Capture folder to write (// is relative to the .blend)")
    camera_model: EnumProperty(name="Camera model", items=CAPTURE_MODELS, default="SIMPLE_PINHOLE",
                               description="The lens model fitted to the photos: keep Simple pinhole for phone "
                                           "photos; a distortion model for wide-angle lenses")
    matcher: EnumProperty(name="Matching", items=[
        ("auto", "Auto", "Sequential for many numbered frames, otherwise every pair"),
        ("exhaustive", "Exhaustive", "Match every pair of photos"),
        ("sequential", "Sequential", "Match each frame with its successors (video)"),
    ], default="auto", description="Which photo pairs are compared to find common points")
    max_features: IntProperty(name="Features", default=2048, min=64, soft_max=16384,
                              description="SIFT features per image")
    upsample_below: IntProperty(name="Upsample below", default=640, min=0, soft_max=4096, subtype="PIXEL",
                                description="SIFT upsamples photos 2x first only when their longer side is below "
                                            "this (0 = never; larger photos: about 3x faster extraction)")
    single_camera: BoolProperty(name="Shared camera", default=False,
                                description="All photos share one camera (one set of intrinsics; about 2x the "
                                            "matching CPU). Pinhole and OpenCV models always share one")
    estimate_focal: BoolProperty(name="Focal from views", default=True,
                                 description="A shared camera starts from the focal length the view graph implies "
                                             "instead of COLMAP's 1.2 x width guess")
    allow_pair: BoolProperty(name="Stereo pair", default=False, description="Accept exactly two photos")
    force: BoolProperty(name="Overwrite", default=False, description="Overwrite an output folder that holds files")
    running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})


# --- Novel views (issue 5): settings of the Synthesize novel views operator --------------------
class MRVM_PG_novel_views(bpy.types.PropertyGroup):
    """Settings of the Synthesize novel views operator."""

    reference_source: EnumProperty(name="References", items=[
        ("DATASET", "Dataset folder", "An object folder of a rendered dataset (rgb/ + pose/)"),
        ("SCENE", "Scene cameras", "Cameras in the scene with a background image (the reference photo)"),
        ("CAPTURE", "Recovered capture", "A capture folder written by Recover poses"),
    ], default="DATASET", description="Where the reference images (the views the model sees) come from")
    dataset_dir: StringProperty(name="Object folder", subtype="DIR_PATH", options=PATH_OPTIONS,
                                description="One object's folder of a rendered dataset (holds rgb/ and pose/)")
    capture_dir: StringProperty(name="Capture", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_capture",
                                description="Capture folder written by Recover poses")
    reference_views: StringProperty(name="Views", default="all",
                                    description="Views of the folder used as references: 'all' (each novel view is "
                                    "rendered from its nearest ones, see Per view) or indices, e.g. '0 1'")
    nearest: IntProperty(name="Per view", default=0, min=0, max=10,
                         description="References each view is rendered from: its nearest ones by direction and "
                         "distance (fewer is faster). 0 = every reference when there are at most 5, else the 5 nearest")
    photo_colours: EnumProperty(name="Photo colours", items=[
        ("AUTO", "Auto", "Lay the references' own colours over each view where they see its surface when each view is "
         "rendered from its nearest of many references (sharper; each reference is rendered once more for its depth)"),
        ("ON", "On", "Always lay the references' own colours over the views where they see the surface"),
        ("OFF", "Off", "The model's own colours only"),
    ], default="AUTO", description="Lay the reference photos' own sharp colours over the novel views where they see "
                                   "the same surface")
    target_source: EnumProperty(name="Targets", items=[
        ("SELECTED", "Selected cameras", "Synthesize the view of every selected camera"),
        ("ORBIT", "Orbit", "Generate cameras on a circle around the 3D cursor"),
    ], default="ORBIT", description="Which cameras get a novel view")
    orbit_count: IntProperty(name="Cameras", default=8, min=1, max=10000, soft_max=120,
                             description="Cameras on the orbit")
    orbit_elevation: FloatProperty(name="Elevation", default=0.3490659, min=-1.5707963, max=1.5707963, subtype="ANGLE",
                                   description="Height of the orbit above the 3D cursor, as an angle")
    orbit_radius: FloatProperty(name="Radius", default=2.0, min=1e-4, soft_max=100.0, subtype="DISTANCE",
                                description="Distance of the orbit cameras from the 3D cursor")
    orbit_fov: FloatProperty(name="Field of view", default=0.6981317, min=0.01745, max=2.967, subtype="ANGLE",
                             description="Field of view of the orbit cameras (along the longer image side)")
    checkpoint: StringProperty(name="Checkpoint", subtype="FILE_PATH", options=PATH_OPTIONS, default="",
                               description="Model checkpoint (model.safetensors or its folder); empty = the shipped model")
    shipped_model: EnumProperty(name="Shipped model", items=SHIPPED_MODELS, default="auto",
                                description="Which shipped model synthesizes when no checkpoint is chosen")
    device: EnumProperty(name="Device", items=DEVICES, default="AUTO", description=DEVICE_TIP)
    quality: EnumProperty(name="Quality", items=QUALITY_LEVELS, default="FULL", description=QUALITY_TIP)
    precision: EnumProperty(name="Precision", items=PRECISION_CHOICES, default="AUTO",
                            description="Number format the model computes in: Auto is the fastest that keeps the "
                                        "images")
    reference_sizing: EnumProperty(name="Reference size", items=[
        ("AUTO", "Auto", "Shrink references larger than the model's training images to that size (the model's "
                         "features are tuned to it; photos also encode much faster)"),
        ("NATIVE", "As they are", "Give the model the references at their own size"),
        ("CUSTOM", "Custom", "Resize the references to a chosen size"),
    ], default="AUTO", description="The size the reference images are given to the model at")
    reference_size: IntProperty(name="Size", default=128, min=1, max=MAX_REFERENCE_SIDE, soft_max=2048,
                                subtype="PIXEL",
                                description="Longer side of the references, in pixels")
    adapt_steps: IntProperty(name="Adapt steps", default=0, min=0, max=100000, soft_max=500,
                             description="Before rendering, fine-tune a copy of the model on these references alone "
                             "(each step holds one reference out); pays with 5 or more references, costs with 2 "
                             "(0 = off)")
    plane_distance: FloatProperty(name="Plane distance", default=1.0, min=1e-4, soft_max=100.0, subtype="DISTANCE",
                                  description="Distance of each image plane from its camera along the view axis (the "
                                              "default: half the default orbit's radius, so the planes float between "
                                              "the cameras and the object, as the command line places them)")
    output: EnumProperty(name="Images", items=IMAGE_OUTPUTS, default="FILES", description=OUTPUT_TIP)
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_novel_views",
                               description="Folder of the novel-view PNG/EXR files (// is relative to the .blend)")
    save_depth: BoolProperty(name="Depth (EXR)", default=False, description="Also save each view's depth map as EXR")
    running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})



# --- Model training (issue 5): settings of the Train / fine-tune operator ---------------------------
class MRVM_PG_train(bpy.types.PropertyGroup):
    """Settings of the Train / fine-tune operator (runs `python -m blender_mrvm train` in the worker)."""

    data_dir: StringProperty(name="Dataset", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_dataset",
                             description="Root of a rendered dataset (ours, SRN, NMR/DVR or NeRF-synthetic)")
    run_dir: StringProperty(name="Run folder", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_runs/run",
                            description="Folder for checkpoints and the metrics log; a run there is continued")
    start_from: EnumProperty(name="Start from", items=[
        ("SHIPPED", "Shipped model", "Fine-tune the model shipped with the add-on on this dataset (no masking phase, "
                                     "lower learning rate): the quickest way to a model of your objects"),
        ("CHECKPOINT", "Checkpoint", "Fine-tune another trained checkpoint (a model file, checkpoint or run folder)"),
        ("NEW", "New model", "Train a model of the chosen size from a random start (MRVM pretraining, then finetuning)"),
    ], default="SHIPPED", description="What training starts from")
    init_checkpoint: StringProperty(name="Checkpoint", subtype="FILE_PATH", options=PATH_OPTIONS, default="",
                                    description="The checkpoint to fine-tune: a model .safetensors file, a checkpoint "
                                                "folder or a run folder")
    keep_losses: BoolProperty(name="Keep its losses", default=False,
                              description="Fine-tune with the losses the model was trained with (the shipped one: "
                                          "LPIPS patches and depth): sharper views (LPIPS -0.02 on new objects of "
                                          "your kind), 0.2 dB lower PSNR, about 1.2x the time a step on a CPU")
    model_kind: EnumProperty(name="Model", items=MODEL_KINDS, default="nerformer_mrvm",
                             description="Kind of model to train (a new one) or to fine-tune (the shipped one)")
    preset: EnumProperty(name="Size", items=[
        ("fast", "Fast", "Smallest model: quick experiments (the shipped GPNR's size)"),
        ("balanced", "Balanced", "The shipped NeRFormer+MRVM's size (about a second per 128 px view on 2 CPU cores)"),
        ("accurate", "Accurate", "Large model: slow on a CPU"),
        ("paper", "Paper", "The paper's size (NeRFormer: 4/5 layer pairs 128 wide, VGG16 encoder, 5.7M parameters; "
                           "GPNR: 8 blocks 256 wide): needs a GPU"),
    ], default="balanced", description="Size of the new model: larger models can be sharper but train and render "
                                       "slower")
    iterations: IntProperty(name="Iterations", default=2000, min=1, soft_max=200000,
                            description="Optimizer steps in all; a continued run trains up to this step")
    checkpoint_every: IntProperty(name="Checkpoint every", default=200, min=1, soft_max=10000,
                                  description="Write a checkpoint every this many steps (cancelling keeps the last one)")
    rays_per_object: IntProperty(name="Rays per object", default=256, min=1, soft_max=4096,
                                 description="Target rays per object per step")
    resume: BoolProperty(name="Continue run", default=True,
                         description="Continue from the run folder's last checkpoint (fine-tune); off starts afresh")
    overwrite_run: BoolProperty(name="Replace the run", default=False, options={"SKIP_SAVE"},
                                description="Continue run is off and the run folder holds a run: remove its "
                                            "checkpoints and metrics and start over (nothing is removed without this)")
    use_for_synthesis: BoolProperty(name="Use for novel views", default=True,
                                    description="When training finishes, pick its checkpoint for Synthesize novel views")
    running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})

# --- Sem2NeRF (issue 12): settings of the Generate from mask operator ---------------------------------
def _is_camera(self, obj) -> bool:
    return obj.type == "CAMERA"


def _show_semantic_changed(self, context) -> None:
    from .scene.sem2nerf import set_show_semantic

    set_show_semantic(self.show_semantic)


class MRVM_PG_sem2nerf(bpy.types.PropertyGroup):
    """Settings of the Sem2NeRF operator (runs `python -m blender_mrvm sem2nerf render` in the worker)."""

    mask_source: EnumProperty(name="Mask", items=[
        ("FILE", "Dataset mask", "A part-id mask PNG of a rendered dataset (mask/NNNNNN.png)"),
        ("IMAGE", "Blender image", "An image painted or opened in Blender's image editor"),
    ], default="FILE", description="Where the part mask (which part of the object each pixel shows) comes from")
    mask_path: StringProperty(name="Mask file", subtype="FILE_PATH", options=PATH_OPTIONS,
                              description="Part-id mask PNG (uint8, the checkpoint's image size)")
    mask_image: PointerProperty(name="Image", type=bpy.types.Image,
                                description="The mask image (the checkpoint's image size, square)")
    mask_encoding: EnumProperty(name="Encoding", items=[
        ("COLORS", "Label colours", "Each pixel has a label's colour (as the semantic maps show them); "
                                    "white, black and transparent are background"),
        ("IDS", "Part ids", "Grey value = part id (a dataset mask opened as an image)"),
    ], default="COLORS", description="How the image's pixels say which part they show")
    edits: StringProperty(name="Relabel", default="",
                          description="Label edits applied to the mask first, e.g. '2:0' (part 2 becomes background) "
                                      "or 'chair/arm:chair/seat' (label names as the panel lists them); several "
                                      "separated by commas")
    viewpoint: EnumProperty(name="Viewpoint", items=[
        ("DATASET", "Dataset pose", "The mask's own pose and intrinsics in its dataset (pose/NNNNNN.txt)"),
        ("CAMERA", "Scene camera", "A camera of the scene sees the mask"),
    ], default="DATASET", description="Which camera the mask is seen from")
    camera: PointerProperty(name="Camera", type=bpy.types.Object, poll=_is_camera,
                            description="The camera the mask is seen from (its frame must be square)")
    checkpoint: StringProperty(name="Checkpoint", subtype="FILE_PATH", options=PATH_OPTIONS, default="",
                               description="Sem2NeRF model (`sem2nerf train` run folder, checkpoint folder or model file); "
                                           "empty = the shipped Sem2NeRF model")
    target_source: EnumProperty(name="Views", items=[
        ("ORBIT", "Orbit", "New cameras on a circle about world z through the mask's camera"),
        ("SELECTED", "Selected cameras", "Generate the view of every selected camera"),
    ], default="ORBIT", description="Which cameras get a generated view")
    orbit_count: IntProperty(name="Cameras", default=8, min=1, soft_max=120, description="Cameras on the orbit")
    style: EnumProperty(name="Style", items=[
        ("MEAN", "Mean", "The average style (the default look)"),
        ("SEED", "Seed", "The style of a random code"),
    ], default="MEAN", description="The object's look (colours, materials) the mask is rendered with")
    style_seed: IntProperty(name="Seed", default=0, min=0, description="Random code of the style")
    mix: FloatProperty(name="Blend", default=0.0, min=0.0, max=1.0, subtype="FACTOR",
                       description="Blend the style toward the style of another seed (0 = off)")
    mix_seed: IntProperty(name="Blend seed", default=1, min=0, description="Random code of the style blended in")
    device: EnumProperty(name="Device", items=DEVICES, default="AUTO", description=DEVICE_TIP)
    quality: EnumProperty(name="Quality", items=QUALITY_LEVELS, default="FULL", description=QUALITY_TIP)
    plane_distance: FloatProperty(name="Plane distance", default=1.0, min=1e-4, soft_max=100.0, subtype="DISTANCE",
                                  description="Distance of each image plane from its camera along the view axis")
    output: EnumProperty(name="Images", items=IMAGE_OUTPUTS, default="FILES", description=OUTPUT_TIP)
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", options=PATH_OPTIONS, default="//mrvm_sem2nerf",
                               description="Folder of the generated images and semantic maps (// is relative to the .blend)")
    show_semantic: BoolProperty(name="Show semantic maps", default=False, update=_show_semantic_changed,
                                description="The Sem2NeRF planes show their semantic maps instead of their images")
    running: BoolProperty(default=False, options={"SKIP_SAVE"})
    progress: FloatProperty(default=0.0, min=0.0, max=1.0, subtype="FACTOR", options={"SKIP_SAVE"})
    status: StringProperty(default="", options={"SKIP_SAVE"})


SCENE_PROPERTIES = {
    "mrvm_capture": MRVM_PG_capture,
    "mrvm_dataset": MRVM_PG_dataset,
    "mrvm_novel_views": MRVM_PG_novel_views,
    "mrvm_sem2nerf": MRVM_PG_sem2nerf,
    "mrvm_train": MRVM_PG_train,
}
classes = tuple(SCENE_PROPERTIES.values())


@persistent
def end_jobs_of_loaded_file(*_args) -> None:
    """``load_post``: no job runs in a file just opened. A section's ``running``, ``progress`` and ``status`` are
    saved in the .blend despite SKIP_SAVE (which keeps them out of presets, not out of files), so a file saved
    while a job ran would open with that section showing a progress bar and refusing to start ("already
    running"); each such section is set idle again, in every scene."""
    _end_jobs()


def end_jobs_after_register() -> None:
    """Timer, once, just after :func:`register`: the same for the file open when the add-on is enabled (opened while
    it was disabled, no ``load_post`` of the add-on saw it), except the sections of jobs started since. A timer since
    ``bpy.data`` cannot be read while Blender registers add-ons at start-up."""
    from .operators._modal import live_sections

    _end_jobs(live_sections())


@persistent
def sync_jobs_after_undo(*_args) -> None:
    """``undo_post`` / ``redo_post``: each section's ``running`` says again whether a job of it runs. Undo and redo
    load a state saved before or during a job (the sections' status is saved in each undo step): Ctrl-Z while a job
    ran set its section idle, so the panel offered its button again and a second job started beside the first (into
    the same dataset or run folder); undoing the result of a job (a Synthesize) went back to a step saved while it
    ran, which showed a progress bar and refused every run ("already running") until the file was opened again.
    Render Dataset's render scenes such a step holds are removed (``operators.dataset``)."""
    from .operators._modal import live_sections
    from .operators.dataset import remove_render_scenes_undo_brought_back

    remove_render_scenes_undo_brought_back()
    live = live_sections()
    _end_jobs(live)
    for scene in bpy.data.scenes:
        for name in SCENE_PROPERTIES:
            group = getattr(scene, name, None)
            if group is not None and not group.running and (scene.session_uid, name) in live:
                group.running = True  # its progress and status come back at the job's next step


def _end_jobs(keep: set = frozenset()) -> None:
    for scene in bpy.data.scenes:
        for name in SCENE_PROPERTIES:
            group = getattr(scene, name, None)
            if group is not None and group.running and (scene.session_uid, name) not in keep:
                group.running, group.progress, group.status = False, 0.0, ""


def _relative_paths():
    """(group, property name, value) of every panel path relative to the .blend (``//``) in every scene."""
    for scene in bpy.data.scenes:
        for name in SCENE_PROPERTIES:
            group = getattr(scene, name, None)
            if group is None:
                continue
            for prop in group.bl_rna.properties:
                if prop.type == "STRING" and prop.subtype in ("FILE_PATH", "DIR_PATH"):
                    value = getattr(group, prop.identifier)
                    if value.startswith("//"):
                        yield group, prop.identifier, value


_rebased: list[tuple] = []
"""What :func:`rebase_paths_on_save` changed for a Save Copy (the open file stays where it was: put back after)."""


@persistent
def rebase_paths_on_save(filepath, *_args) -> None:
    """``save_pre``: on Save As into another folder, the panel's ``//`` paths are rebased onto the new location, so
    they name the same folders and files as before, as Blender's Remap Relative does for images and libraries (they
    were left as typed: Render Dataset rendered a whole new dataset beside the new .blend instead of resuming, and
    Synthesize looked for its references there). Paths on another drive become absolute."""
    import os

    old = bpy.data.filepath
    _rebased.clear()
    if not old or not filepath or os.path.dirname(os.path.abspath(old)) == os.path.dirname(os.path.abspath(filepath)):
        return
    new_dir = os.path.dirname(os.path.abspath(filepath))
    for group, ident, value in list(_relative_paths()):
        target = bpy.path.abspath(value, start=os.path.dirname(old))
        try:
            rebased = "//" + os.path.relpath(target, new_dir).replace(os.sep, "/")
        except ValueError:  # another drive (Windows): no relative path
            rebased = os.path.normpath(target)
        if value.endswith(("/", os.sep)) and not rebased.endswith("/"):
            rebased += "/"
        if rebased != value:
            setattr(group, ident, rebased)
            _rebased.append((group, ident, value))


@persistent
def restore_paths_after_copy(filepath, *_args) -> None:
    """``save_post``: after a Save Copy the open file is still the old one: its paths are put back."""
    import os

    if _rebased and os.path.abspath(bpy.data.filepath or "") != os.path.abspath(filepath or ""):
        for group, ident, value in _rebased:
            setattr(group, ident, value)
    _rebased.clear()


@persistent
def keep_job_data_out_of_saves(*_args) -> None:
    """``save_pre``: what running jobs made for themselves stays out of the file (``operators.dataset``: Render
    Dataset's render scene)."""
    from .operators.dataset import keep_render_scenes_out_of_saves

    keep_render_scenes_out_of_saves()


_HANDLERS = (("load_post", end_jobs_of_loaded_file), ("save_pre", rebase_paths_on_save),
             ("save_pre", keep_job_data_out_of_saves),
             ("save_post", restore_paths_after_copy), ("undo_post", sync_jobs_after_undo),
             ("redo_post", sync_jobs_after_undo))


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    for name, cls in SCENE_PROPERTIES.items():
        setattr(bpy.types.Scene, name, PointerProperty(type=cls))
    for when, fn in _HANDLERS:
        if fn not in getattr(bpy.app.handlers, when):
            getattr(bpy.app.handlers, when).append(fn)
    if not bpy.app.timers.is_registered(end_jobs_after_register):
        bpy.app.timers.register(end_jobs_after_register, first_interval=0)


def unregister() -> None:
    if bpy.app.timers.is_registered(end_jobs_after_register):
        bpy.app.timers.unregister(end_jobs_after_register)
    for when, fn in _HANDLERS:
        while fn in getattr(bpy.app.handlers, when):
            getattr(bpy.app.handlers, when).remove(fn)
    for name in SCENE_PROPERTIES:
        if hasattr(bpy.types.Scene, name):
            delattr(bpy.types.Scene, name)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
