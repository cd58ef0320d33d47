"""Object categories of the synthetic world: sizes, placement rules, colours and language.

A category name is at once the ground-truth class, the label a perfect detector reports and
the class name the evaluation queries with. `confusions` are labels a noisy detector may
report instead (synonyms and near neighbours); `paraphrases` are natural queries that should
retrieve the category and no other category of this table.

Sizes are (min, max) metres for width (along the wall / the object's own x), depth (front to
back) and height, of the object's whole axis-aligned box in its own frame.
"""

from __future__ import annotations

from dataclasses import dataclass

Range = tuple[float, float]
RGB = tuple[int, int, int]

PLACEMENTS: tuple[str, ...] = ("floor_wall", "floor_free", "on_surface", "wall", "ceiling")
ROOM_TYPES: tuple[str, ...] = ("living_room", "kitchen", "office", "bedroom")
BACKGROUND_CLASSES: tuple[str, ...] = ("floor", "wall", "ceiling")


@dataclass(frozen=True)
class Category:
    """One object category and how it appears in procedural scenes."""

    name: str
    """Class name, detection label and evaluation class (lower case, words separated by spaces)."""
    size_m: tuple[Range, Range, Range]
    """(min, max) of width x depth x height in metres."""
    placement: str
    """One of PLACEMENTS: how the object is put into a room."""
    rooms: tuple[str, ...]
    """Room types the category appears in."""
    colors: tuple[RGB, ...]
    """Base colours; each instance picks one and varies it slightly."""
    confusions: tuple[str, ...]
    """Semantically close labels a noisy detector may output instead of `name`."""
    paraphrases: tuple[str, ...]
    """Natural-language queries that should retrieve this category (and no other)."""
    is_surface: bool = False
    """Small objects may be put on (or in) it."""


# Shared palettes: a few realistic material colours rather than random RGB.
_WOOD = ((196, 160, 112), (150, 105, 65), (110, 78, 52), (222, 200, 165))
_PAINTED = ((236, 234, 228), (60, 60, 62), (170, 180, 185), (120, 140, 120))
_FABRIC = ((120, 120, 126), (45, 60, 95), (200, 186, 160), (75, 110, 85), (150, 70, 60))
_METAL = ((190, 192, 195), (70, 72, 75), (235, 235, 232))
_CERAMIC = ((240, 238, 230), (200, 60, 50), (60, 110, 170), (230, 190, 60), (40, 40, 40))

_L, _K, _O, _B = "living_room", "kitchen", "office", "bedroom"
_ALL = (_L, _K, _O, _B)


def _c(
    name: str,
    size: tuple[Range, Range, Range],
    placement: str,
    rooms: tuple[str, ...],
    colors: tuple[RGB, ...],
    confusions: tuple[str, ...],
    paraphrases: tuple[str, ...],
    surface: bool = False,
) -> Category:
    return Category(name, size, placement, rooms, colors, confusions, paraphrases, surface)


# The table is aligned by hand for reading; the formatter would spread it over 600 lines.
# fmt: off
_TABLE: tuple[Category, ...] = (
    # --- seating and tables -------------------------------------------------------------
    _c("sofa", ((1.8, 2.2), (0.85, 0.95), (0.8, 0.9)), "floor_wall", (_L,), _FABRIC,
       ("couch", "loveseat"),
       ("a comfy couch to lie on", "a long upholstered seat for three people")),
    _c("armchair", ((0.75, 0.9), (0.75, 0.9), (0.8, 0.95)), "floor_free", (_L, _B, _O), _FABRIC,
       ("chair", "sofa"),
       ("a cosy padded seat for one person with arm rests", "an upholstered easy chair")),
    _c("coffee table", ((0.9, 1.2), (0.5, 0.7), (0.4, 0.48)), "floor_free", (_L,), _WOOD,
       ("table", "side table"),
       ("the low table in front of the couch", "a low lounge table to put drinks on"), True),
    _c("dining table", ((1.2, 1.7), (0.8, 0.95), (0.74, 0.78)), "floor_free", (_K, _L), _WOOD,
       ("table", "kitchen table"),
       ("the table where we eat dinner", "a large table for family meals"), True),
    _c("desk", ((1.2, 1.6), (0.6, 0.75), (0.72, 0.76)), "floor_wall", (_O, _B), _WOOD + _PAINTED,
       ("table", "writing desk"),
       ("a work desk for the computer", "the writing table in the study"), True),
    _c("chair", ((0.42, 0.5), (0.45, 0.52), (0.82, 0.95)), "floor_free", _ALL, _WOOD + _PAINTED,
       ("stool", "seat"),
       ("a simple wooden chair with four legs", "a dining chair with a backrest")),
    _c("office chair", ((0.6, 0.68), (0.6, 0.68), (0.95, 1.1)), "floor_free", (_O,),
       ((30, 30, 32), (60, 62, 70), (40, 55, 90)),
       ("chair", "desk chair"),
       ("a swivel chair on wheels", "an adjustable ergonomic computer chair")),
    _c("ottoman", ((0.5, 0.7), (0.5, 0.7), (0.4, 0.45)), "floor_free", (_L, _B), _FABRIC,
       ("footstool", "pouf"),
       ("a padded footstool", "a pouf to rest your feet on")),
    _c("bar stool", ((0.38, 0.42), (0.38, 0.42), (0.65, 0.75)), "floor_free", (_K,),
       _METAL + ((30, 30, 32),),
       ("stool", "chair"),
       ("a tall stool at the breakfast bar", "a high seat without a backrest")),
    # --- bedroom and storage ------------------------------------------------------------
    _c("bed", ((1.4, 1.8), (2.0, 2.2), (0.9, 1.1)), "floor_wall", (_B,), _WOOD + _FABRIC[:3],
       ("double bed", "mattress"),
       ("somewhere to sleep at night", "a double bed with pillows and a duvet"), True),
    _c("nightstand", ((0.4, 0.5), (0.35, 0.45), (0.5, 0.6)), "floor_wall", (_B,), _WOOD + _PAINTED,
       ("bedside table", "side table"),
       ("the small bedside table", "a little bedside cupboard with a drawer"), True),
    _c("dresser", ((0.9, 1.4), (0.45, 0.55), (0.75, 0.95)), "floor_wall", (_B,),
       _WOOD + _PAINTED,
       ("chest of drawers", "cabinet"),
       ("a chest of drawers for folded clothes", "a low bedroom dresser with drawers"), True),
    _c("wardrobe", ((1.0, 1.8), (0.55, 0.62), (1.9, 2.15)), "floor_wall", (_B,), _WOOD + _PAINTED,
       ("closet", "cabinet"),
       ("a tall closet to hang clothes in", "a freestanding armoire")),
    _c("bookshelf", ((0.8, 1.2), (0.3, 0.38), (1.6, 2.0)), "floor_wall", (_L, _O, _B),
       _WOOD + _PAINTED,
       ("bookcase", "shelf"),
       ("a tall shelf full of books", "a bookcase standing against the wall"), True),
    _c("tv stand", ((1.2, 1.8), (0.4, 0.5), (0.45, 0.6)), "floor_wall", (_L,), _WOOD + _PAINTED,
       ("cabinet", "media console"),
       ("the low media console under the television", "a low bench for the tv"), True),
    _c("cabinet", ((0.8, 1.2), (0.4, 0.5), (0.8, 1.0)), "floor_wall", (_L, _O), _WOOD + _PAINTED,
       ("cupboard", "sideboard"),
       ("a storage cupboard with doors", "a sideboard for storing things"), True),
    _c("filing cabinet", ((0.4, 0.5), (0.55, 0.62), (0.7, 1.3)), "floor_wall", (_O,), _METAL,
       ("cabinet", "drawers"),
       ("a metal cabinet with drawers for documents", "where office paperwork is filed"), True),
    # --- kitchen ------------------------------------------------------------------------
    _c("kitchen counter", ((0.8, 1.6), (0.6, 0.64), (0.88, 0.92)), "floor_wall", (_K,),
       _PAINTED + _WOOD[:2],
       ("countertop", "cabinet"),
       ("the countertop where food is prepared", "a kitchen worktop with cupboards below"),
       True),
    _c("sink", ((0.7, 0.9), (0.6, 0.64), (0.88, 0.92)), "floor_wall", (_K,), _PAINTED,
       ("kitchen sink", "basin"),
       ("where I wash the dishes by hand", "a kitchen basin with a tap")),
    _c("refrigerator", ((0.6, 0.8), (0.65, 0.72), (1.7, 1.9)), "floor_wall", (_K,), _METAL,
       ("fridge", "freezer"),
       ("the fridge where food is kept cold", "a tall fridge freezer")),
    _c("stove", ((0.6, 0.6), (0.6, 0.64), (0.88, 0.92)), "floor_wall", (_K,),
       ((235, 235, 232), (60, 62, 66), (190, 192, 195)),
       ("oven", "cooker"),
       ("a cooker with burners to cook on", "the hob and oven"), True),
    _c("dishwasher", ((0.6, 0.6), (0.6, 0.62), (0.84, 0.86)), "floor_wall", (_K,), _METAL,
       ("washing machine", "oven"),
       ("the appliance that cleans dirty plates", "a dish washing machine")),
    _c("microwave", ((0.45, 0.52), (0.34, 0.4), (0.26, 0.3)), "on_surface", (_K,),
       ((235, 235, 232), (40, 40, 42), (190, 192, 195)),
       ("oven", "toaster oven"),
       ("something to reheat leftovers quickly", "a microwave oven")),
    _c("toaster", ((0.26, 0.3), (0.16, 0.2), (0.18, 0.21)), "on_surface", (_K,),
       _METAL + ((200, 40, 40),),
       ("kettle", "bread maker"),
       ("a machine to toast slices of bread", "a pop-up toaster")),
    _c("kettle", ((0.2, 0.24), (0.15, 0.18), (0.22, 0.26)), "on_surface", (_K,),
       _METAL + ((240, 238, 230),),
       ("teapot", "coffee maker"),
       ("something to boil water for tea", "an electric water kettle")),
    _c("coffee maker", ((0.2, 0.25), (0.25, 0.3), (0.3, 0.38)), "on_surface", (_K, _O),
       ((30, 30, 32), (190, 192, 195), (200, 40, 40)),
       ("espresso machine", "kettle"),
       ("a machine that brews coffee", "an espresso machine")),
    _c("cooking pot", ((0.26, 0.32), (0.2, 0.26), (0.13, 0.18)), "on_surface", (_K,),
       _METAL + ((40, 40, 42),),
       ("pan", "saucepan"),
       ("a pot with a lid for making soup", "a stockpot to boil pasta in")),
    _c("cutting board", ((0.3, 0.42), (0.2, 0.28), (0.018, 0.025)), "on_surface", (_K,),
       _WOOD[:2] + ((235, 235, 232),),
       ("chopping board", "tray"),
       ("a board for chopping vegetables", "a wooden chopping board")),
    _c("bowl", ((0.14, 0.2), (0.14, 0.2), (0.06, 0.09)), "on_surface", (_K, _L), _CERAMIC,
       ("plate", "dish"),
       ("a bowl for cereal or soup", "a round ceramic dish")),
    _c("mug", ((0.1, 0.12), (0.075, 0.085), (0.085, 0.1)), "on_surface", (_K, _L, _O, _B),
       _CERAMIC,
       ("cup", "coffee cup"),
       ("a cup of coffee with a handle", "something to drink hot tea from")),
    _c("bottle", ((0.065, 0.08), (0.065, 0.08), (0.24, 0.32)), "on_surface", (_K, _L, _O),
       ((60, 120, 70), (120, 170, 210), (110, 40, 50), (230, 230, 225)),
       ("water bottle", "vase"),
       ("a bottle of water", "a glass wine bottle")),
    # --- decoration ---------------------------------------------------------------------
    _c("vase", ((0.1, 0.16), (0.1, 0.16), (0.2, 0.35)), "on_surface", (_L, _K, _B),
       ((60, 110, 170), (240, 238, 230), (190, 120, 80), (60, 60, 62)),
       ("bottle", "flower pot"),
       ("a vase with flowers", "a decorative flower container")),
    _c("potted plant", ((0.35, 0.5), (0.35, 0.5), (0.7, 1.3)), "floor_free", _ALL,
       ((70, 120, 60), (50, 100, 55), (95, 140, 70)),
       ("plant", "houseplant", "tree"),
       ("a green houseplant in a pot", "an indoor plant with leaves")),
    _c("floor lamp", ((0.3, 0.4), (0.3, 0.4), (1.5, 1.8)), "floor_free", (_L, _B, _O),
       ((240, 232, 210), (230, 225, 215), (210, 200, 180)),
       ("lamp", "light"),
       ("a tall standing lamp", "a light on a long pole standing on the floor")),
    _c("table lamp", ((0.25, 0.35), (0.25, 0.35), (0.4, 0.55)), "on_surface", (_L, _O, _B),
       ((240, 232, 210), (230, 225, 215), (200, 215, 225)),
       ("lamp", "light"),
       ("a small lamp with a shade on a table", "a reading lamp with a small shade")),
    _c("picture frame", ((0.15, 0.25), (0.08, 0.1), (0.2, 0.3)), "on_surface", (_L, _O, _B),
       ((30, 30, 32), (196, 160, 112), (236, 234, 228), (180, 150, 60)),
       ("photo", "painting"),
       ("a framed family photo standing on a shelf", "a small photo frame")),
    _c("candle", ((0.06, 0.08), (0.06, 0.08), (0.08, 0.15)), "on_surface", (_L, _B, _K),
       ((245, 240, 225), (200, 60, 50), (230, 200, 150)),
       ("vase", "bottle"),
       ("a scented wax candle", "a candle with a wick")),
    _c("teddy bear", ((0.22, 0.28), (0.16, 0.2), (0.26, 0.32)), "on_surface", (_B,),
       ((150, 100, 60), (200, 170, 130), (230, 230, 225)),
       ("toy", "stuffed animal"),
       ("a cuddly stuffed toy", "a plush bear for a child")),
    # --- electronics and office ---------------------------------------------------------
    _c("laptop", ((0.32, 0.36), (0.24, 0.27), (0.2, 0.23)), "on_surface", (_O, _L, _B),
       ((190, 192, 195), (40, 40, 42)),
       ("computer", "notebook"),
       ("a portable computer", "an open notebook computer")),
    _c("monitor", ((0.5, 0.65), (0.18, 0.22), (0.38, 0.5)), "on_surface", (_O,),
       ((30, 30, 32), (60, 62, 66)),
       ("tv", "screen"),
       ("a computer screen on a stand", "a pc display")),
    _c("keyboard", ((0.42, 0.46), (0.13, 0.15), (0.025, 0.035)), "on_surface", (_O,),
       ((30, 30, 32), (220, 220, 215)),
       ("laptop", "keypad"),
       ("something to type on", "a computer keyboard")),
    _c("printer", ((0.4, 0.46), (0.35, 0.4), (0.2, 0.25)), "on_surface", (_O,),
       ((220, 220, 215), (40, 40, 42)),
       ("scanner", "copier"),
       ("a machine that prints documents", "an inkjet printer")),
    _c("keys", ((0.07, 0.09), (0.035, 0.05), (0.012, 0.018)), "on_surface", _ALL,
       ((200, 170, 60), (190, 192, 195)),
       ("keychain", "key"),
       ("where are my keys", "a bunch of house keys on a ring")),
    _c("remote control", ((0.17, 0.21), (0.045, 0.055), (0.018, 0.024)), "on_surface", (_L, _B),
       ((30, 30, 32), (70, 72, 75), (220, 220, 215)),
       ("phone", "remote"),
       ("the remote for the television", "a clicker to change channels")),
    _c("cell phone", ((0.07, 0.078), (0.145, 0.16), (0.008, 0.01)), "on_surface", _ALL,
       ((30, 30, 32), (220, 220, 215), (60, 90, 140)),
       ("phone", "remote control"),
       ("my mobile phone", "a smartphone")),
    _c("speaker", ((0.14, 0.2), (0.14, 0.2), (0.2, 0.3)), "on_surface", (_L, _O),
       ((30, 30, 32), (220, 220, 215), (110, 78, 52)),
       ("subwoofer", "radio"),
       ("a loudspeaker for music", "a bluetooth speaker")),
    _c("book", ((0.15, 0.22), (0.2, 0.26), (0.025, 0.05)), "on_surface", (_L, _O, _B, _K),
       ((160, 40, 40), (40, 70, 130), (50, 110, 70), (220, 180, 60), (30, 30, 32),
        (230, 225, 210)),
       ("notebook", "magazine"),
       ("a novel to read", "a hardcover book")),
    _c("backpack", ((0.3, 0.34), (0.18, 0.22), (0.42, 0.48)), "floor_free", (_O, _B),
       ((40, 55, 90), (30, 30, 32), (150, 70, 60), (75, 110, 85)),
       ("bag", "suitcase"),
       ("a school bag", "a rucksack to carry things")),
    _c("cardboard box", ((0.3, 0.5), (0.3, 0.45), (0.25, 0.4)), "floor_free", (_O, _B),
       ((180, 140, 95), (165, 125, 85)),
       ("box", "package"),
       ("a brown shipping box", "a moving carton")),
    _c("trash can", ((0.25, 0.35), (0.25, 0.35), (0.35, 0.6)), "floor_free", (_K, _O, _B),
       _METAL + ((30, 30, 32),),
       ("bin", "bucket"),
       ("a bin to throw rubbish away", "a wastebasket")),
    # --- on the walls and ceiling -------------------------------------------------------
    _c("tv", ((1.0, 1.45), (0.06, 0.08), (0.6, 0.85)), "wall", (_L, _B), ((25, 25, 28),),
       ("monitor", "television"),
       ("the television", "a flat screen to watch movies")),
    _c("painting", ((0.5, 1.2), (0.03, 0.04), (0.4, 0.9)), "wall", _ALL,
       ((30, 30, 32), (196, 160, 112), (236, 234, 228), (180, 150, 60)),
       ("picture", "poster"),
       ("a piece of art hanging on the wall", "a canvas painting")),
    _c("clock", ((0.25, 0.35), (0.04, 0.05), (0.25, 0.35)), "wall", _ALL,
       ((30, 30, 32), (196, 160, 112), (236, 234, 228)),
       ("plate", "timer"),
       ("a clock on the wall that tells the time", "a round wall clock")),
    _c("mirror", ((0.4, 0.7), (0.03, 0.04), (0.6, 1.1)), "wall", (_B, _L),
       ((30, 30, 32), (196, 160, 112), (180, 150, 60)),
       ("window", "picture"),
       ("a looking glass to check my reflection", "a wall mirror")),
    _c("wall shelf", ((0.6, 1.1), (0.2, 0.25), (0.14, 0.18)), "wall", (_L, _O, _B),
       _WOOD + ((236, 234, 228),),
       ("shelf", "bookshelf"),
       ("a floating shelf mounted on the wall", "a plank shelf on brackets"), True),
    _c("whiteboard", ((1.2, 1.8), (0.04, 0.06), (0.9, 1.2)), "wall", (_O,), ((245, 245, 245),),
       ("blackboard", "screen"),
       ("a board to write on with markers", "a dry erase board")),
    _c("window", ((0.8, 1.5), (0.05, 0.07), (1.0, 1.4)), "wall", _ALL,
       ((236, 234, 228), (60, 62, 66), (150, 105, 65)),
       ("mirror", "door"),
       ("a window to look outside", "a glass pane in the outer wall")),
    _c("wall cabinet", ((0.6, 1.2), (0.32, 0.36), (0.65, 0.75)), "wall", (_K,), _PAINTED,
       ("cabinet", "cupboard"),
       ("the upper kitchen cupboard on the wall", "a wall-mounted cupboard above the worktop")),
    _c("air conditioner", ((0.75, 0.9), (0.2, 0.24), (0.27, 0.3)), "wall", (_L, _O, _B),
       ((240, 240, 236),),
       ("heater", "fan"),
       ("the ac unit that cools the room", "a wall-mounted air conditioning unit")),
    _c("ceiling light", ((0.3, 0.5), (0.3, 0.5), (0.08, 0.14)), "ceiling", _ALL,
       ((250, 246, 230), (240, 240, 240)),
       ("lamp", "light"),
       ("the light fixture on the ceiling", "an overhead lamp")),
    _c("ceiling fan", ((1.0, 1.2), (1.0, 1.2), (0.3, 0.45)), "ceiling", (_L, _B),
       ((236, 234, 228), (110, 78, 52), (60, 62, 66)),
       ("fan", "ceiling light"),
       ("a fan with blades hanging from the ceiling", "an overhead rotating fan")),
)
# fmt: on

CATEGORIES: dict[str, Category] = {c.name: c for c in _TABLE}
"""All object categories by name (background classes are not in here)."""

if len(CATEGORIES) != len(_TABLE):  # pragma: no cover - guards edits of the table above
    raise RuntimeError("duplicate category names in the category table")


def is_background(category: str) -> bool:
    """True for floor, wall and ceiling (never reported as detections)."""
    return category in BACKGROUND_CLASSES
