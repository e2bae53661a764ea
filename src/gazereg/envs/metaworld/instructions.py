"""Natural-language instructions for Meta-World tasks: one sentence per task, a generic fallback otherwise."""

from __future__ import annotations

import re

INSTRUCTIONS: dict[str, str] = {
    "assembly-v3": "Pick up the nut and place it onto the peg.",
    "basketball-v3": "Pick up the basketball and dunk it into the hoop.",
    "bin-picking-v3": "Pick up the cube and place it into the other bin.",
    "box-close-v3": "Pick up the lid and put it on the box to close it.",
    "button-press-topdown-v3": "Press the button from the top.",
    "button-press-topdown-wall-v3": "Press the button from the top, reaching over the wall.",
    "button-press-v3": "Press the button from the front.",
    "button-press-wall-v3": "Press the button from the front, reaching around the wall.",
    "coffee-button-v3": "Push the button on the coffee machine.",
    "coffee-pull-v3": "Pull the mug out from under the coffee machine.",
    "coffee-push-v3": "Push the mug under the coffee machine.",
    "dial-turn-v3": "Rotate the dial half a turn.",
    "disassemble-v3": "Pick the nut up off the peg.",
    "door-close-v3": "Close the door.",
    "door-lock-v3": "Lock the door by turning the lock down.",
    "door-open-v3": "Open the door.",
    "door-unlock-v3": "Unlock the door by turning the lock up.",
    "hand-insert-v3": "Put your hand into the hole.",
    "drawer-close-v3": "Push the drawer closed.",
    "drawer-open-v3": "Pull the drawer open.",
    "faucet-open-v3": "Turn the faucet handle to open it.",
    "faucet-close-v3": "Turn the faucet handle to close it.",
    "hammer-v3": "Pick up the hammer and hammer the nail into the wall.",
    "handle-press-side-v3": "Press the handle down from the side.",
    "handle-press-v3": "Press the handle down.",
    "handle-pull-side-v3": "Pull the handle up from the side.",
    "handle-pull-v3": "Pull the handle up.",
    "lever-pull-v3": "Pull the lever up.",
    "pick-place-wall-v3": "Pick up the puck and place it at the goal behind the wall.",
    "pick-out-of-hole-v3": "Pick the puck out of the hole.",
    "pick-place-v3": "Pick up the puck and place it at the goal.",
    "plate-slide-v3": "Slide the plate into the goal.",
    "plate-slide-side-v3": "Slide the plate sideways into the goal.",
    "plate-slide-back-v3": "Slide the plate back out of the goal.",
    "plate-slide-back-side-v3": "Slide the plate sideways back out of the goal.",
    "peg-insert-side-v3": "Pick up the peg and insert it into the hole from the side.",
    "peg-unplug-side-v3": "Unplug the peg from the hole.",
    "soccer-v3": "Kick the ball into the goal.",
    "stick-push-v3": "Grasp the stick and push the box with it.",
    "stick-pull-v3": "Grasp the stick and pull the box with it.",
    "push-v3": "Push the puck to the goal.",
    "push-wall-v3": "Push the puck around the wall to the goal.",
    "push-back-v3": "Pull the puck back to the goal.",
    "reach-v3": "Reach the goal with the gripper.",
    "reach-wall-v3": "Reach over the wall to the goal.",
    "shelf-place-v3": "Pick up the puck and place it on the shelf.",
    "sweep-into-v3": "Sweep the puck into the hole.",
    "sweep-v3": "Sweep the puck off the table.",
    "window-open-v3": "Slide the window open.",
    "window-close-v3": "Slide the window closed.",
}


def instruction_for(task: str) -> str:
    """The sentence for a Meta-World task name; unknown tasks get "Perform the task: <words>." from the name."""
    if task in INSTRUCTIONS:
        return INSTRUCTIONS[task]
    words = re.sub(r"-v\d+$", "", task).replace("-", " ").replace("_", " ").strip()
    if not words:
        raise ValueError(f"cannot make an instruction from the empty task name {task!r}")
    return f"Perform the task: {words}."
