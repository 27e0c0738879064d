"""Setting labels: the paper's train/deploy settings, named with the method variant when it is not the paper's."""

from __future__ import annotations


def setting_name(train_input: str, deploy_input: str, variant: str = "paper") -> str:
    """TGDG, TGDE, TEDE or TEDG from the training and deployment inputs; another method than the paper's is named
    after it: 'TGDG (reference-code)'."""
    code = {"gt": "G", "estimated": "E"}
    name = f"T{code[train_input]}D{code[deploy_input]}"
    return name if variant == "paper" else f"{name} ({variant})"


def base_setting(setting: str) -> str:
    """The paper's setting of a label: 'TGDG (reference-code)' -> 'TGDG'."""
    return setting.split(" (", 1)[0]

