"""How LIBERO's objects are called in plain language: the one lexicon both sides share.

The scripted expert writes its sub-plans with these phrases and the oracle verifier grounds
sub-plan text back to objects with them (plus its own synonyms), so the two agree by
construction. It lives in `sim` because it describes the simulator's object names, not any
policy; neither the expert nor the oracle has to import the other.
"""

from __future__ import annotations

import re

# How an object category is called, most specific first; the first phrase found in the
# instruction wins, so the plan echoes the instruction's wording ("cream cheese box", or
# "box of cheese" in the object-property suite), as a reasoning VLA would.
NAMES: dict[str, tuple[str, ...]] = {
    "alphabet_soup": ("alphabet soup", "can of soup"),
    "tomato_sauce": ("tomato sauce", "can of sauce"),
    "cream_cheese": ("cream cheese box", "box of cheese", "cream cheese"),
    "butter": ("box of butter", "butter"),
    "ketchup": ("ketchup",),
    "milk": ("milk",),
    "orange_juice": ("orange juice",),
    "chocolate_pudding": ("chocolate pudding", "brown chocolate"),
    "new_salad_dressing": ("salad dressing",),
    "bbq_sauce": ("bbq sauce",),
    "porcelain_mug": ("white mug", "pure white cup"),
    "white_yellow_mug": ("yellow and white mug", "middle mug"),
    "red_coffee_mug": ("red mug",),
    "akita_black_bowl": ("black bowl", "middle bowl", "bowl"),
    "white_bowl": ("white bowl", "bowl"),
    "moka_pot": ("moka pot", "moka machine", "moka coffee maker"),
    "chefmate_8_frypan": ("frying pan",),
    "black_book": ("book",),
    "yellow_book": ("book",),
    "wine_bottle": ("wine bottle",),
    "plate": ("plate",),
    "basket": ("basket",),
    "wooden_tray": ("tray",),
    "flat_stove": ("stove", "cooktop"),
    "microwave": ("microwave",),
    "white_cabinet": ("cabinet",),
    "wooden_cabinet": ("cabinet",),
    "wine_rack": ("wine rack",),
    "desk_caddy": ("caddy",),
    "wooden_two_layer_shelf": ("cabinet shelf", "shelf"),
}

def category(name: str) -> str:
    """``alphabet_soup_1`` -> ``alphabet_soup``."""
    return re.sub(r"_\d+$", "", name)
