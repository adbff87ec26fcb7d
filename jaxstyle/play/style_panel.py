"""The ``jaxstyle play`` page's steering and style controls (:class:`StylePanel`, a part of
:class:`jaxstyle.play.server.PlayServer`): the walk buttons and keys, adding and removing
characters, the style choice and the blend of up to three styles with its weights.
"""

from __future__ import annotations

NO_BLEND = "(none)"
STEER_BUTTONS = {"Left": "A", "Forward": "W", "Back": "S", "Right": "D"}


class StylePanel:
    """The steering and style half of :class:`jaxstyle.play.server.PlayServer` (which inherits it).
    It uses the server's ``session``, the page's controls ``_gui`` and ``camera_yaw``."""

    def session_remove(self) -> None:
        self.session.remove_character()

    def press(self, key: str, run: bool = False) -> None:
        """A steering key, as the page's hotkeys send it."""
        self.session.key(key, self.camera_yaw(), run=run)

    def _on_steer(self, which: str) -> None:
        if which == "Stop":
            self.session.stop()
        else:
            self.press(STEER_BUTTONS[which])

    def _refresh_style_options(self) -> None:
        names = list(self.session.styles)
        g = self._gui
        g["style"].options = names
        g["style"].value = self.session.characters[0].style
        for k, handle in enumerate(g["blend"]):
            handle.options = [NO_BLEND] + names
            if handle.value not in handle.options:
                handle.value = NO_BLEND
            if handle.value == NO_BLEND and k < 2 and len(names) > k:
                handle.value = names[k]

    def _on_style(self) -> None:
        name = self._gui["style"].value
        first = self.session.characters[0]
        if name in self.session.styles and (name != first.style or first.blend is not None):
            self.session.set_style(name, 0)

    def _blend_choice(self):
        names, weights = [], []
        for handle, w in zip(self._gui["blend"], self._gui["weights"], strict=True):
            if handle.value != NO_BLEND and handle.value not in names:
                names.append(handle.value)
                weights.append(w.value)
        return names, weights

    def _on_blend(self) -> None:
        names, weights = self._blend_choice()
        self.session.set_blend(names, weights, 0)

    def _on_blend_change(self) -> None:
        if self.session.characters[0].blend is not None:
            self._on_blend()  # a blend playing follows its sliders from the next frame on

    def set_style(self, name: str) -> None:
        """Switch the first character, as the dropdown does (tests and scripts)."""
        self._gui["style"].value = name
