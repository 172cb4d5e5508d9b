"""What the studio adds to viser's page: the E-STOP key, and nothing that hides the E-STOP or publishes the page.

viser's client is a prebuilt bundle; the studio serves it through its own request handler (web/guard.py), which
puts this script and style into the page's ``<head>``:

- **Escape stops the robot from anywhere on the page** — focus in a text or number field included, a menu open
  included: a key listener on the window, in the capture phase (before any field or menu sees the key), clicks the
  E-STOP button. Typing never produces Escape. The key still does what it did (a menu still closes).
- viser's *Configuration & diagnostics* toggle is hidden: it replaced the whole panel, E-STOP included, with the
  scene tree; so is the dock's *Collapse panel area*, which folded the side panel, E-STOP included, into a strip
  (and left Escape nothing to press). (The *Share* button, which offers a public URL of the page, is turned off by
  the theme.)
- **A number field is committed, not sent at every keystroke**: viser sends each keystroke's number, so typing
  ``-0.1`` sent ``-0`` (which the field then showed as ``0``, and the next keys made ``0.1``: a refusal became a
  clamp) and typing ``1.5`` was validated at ``1.``. The field's input events are held back from the page's
  handlers until Enter, Tab, a step arrow or leaving the field, then the field's text is sent once.
  A slider's number box refuses a number outside the slider's range, and says the range under it: the box clamped
  it to the nearest end without a word (the Replay tab's time took -5 as 0 and 46 as a 30 s recording's end); and a
  number with more decimals than its slider takes (web.inputs.SLIDER_DECIMALS: 2.5 into State picked state 2).
  Every other number field takes web.inputs.DIGITS decimal places (its formatter rounds to the field's precision,
  which viser derived from the step: 2.5 in a field of step 1 was sent as 2); a number with more is refused.
- **A click on a state selects it** — a row of the state grid (its inputs included) or a cell of the states table:
  viser sends no clicks of its own for these, so the script writes ``automaton:index:count`` into a hidden text
  field of the editor (``CLICKED_FIELD``), whose update the editor takes as a selection.
- **A double-click in a number field selects the whole number**: the browser selected a word, and ``-33.5``
  became ``33.5`` selected, so typing over it kept the minus.
- **``?maxFps=N`` caps the page's frames** (1 to 59 a second; anything else leaves the page as it is; without the
  parameter, the studio's ``--max-fps``): a browser without a GPU draws WebGL in software on the CPU, and a moving
  robot keeps the 3D view drawing at the display's rate, about a core of a laptop (bench/studio.py). The page's
  animation frames (``requestAnimationFrame``, which the 3D view, the plots and the panels draw in) are run together
  at most N times a second, all callbacks of one frame in one frame, so the view stays in step with itself and only
  its rate changes.
- **Text in the panels wraps, even a word longer than the panel**: a recording's name, a node's or a record type's
  (the Replay tab lists them; the status line and the robot bar repeat a name) has no space to break at: it ran
  past the panel's edge, and it widened the side panel's scroll area, which scrolled sideways (the area is as wide
  as its widest unbreakable word). Anywhere, not only at a word's end: that takes the word out of the width.
- **A browser without a GPU draws the 3D view at a lower resolution**: when WebGL's renderer is a software one
  (SwiftShader, llvmpipe: what viser's own "Software WebGL rendering detected" notice looks for) and the URL does
  not choose a resolution, the page adds viser's ``fixedDpr`` (SOFTWARE_RENDER_SCALE of the screen's pixel ratio) to
  its URL before viser reads it: every pixel is shaded on the CPU, and a 32-module robot in a full-resolution view
  was drawn at about 12 frames a second (bench/studio.py). ``?fixedDpr=1`` in the URL keeps full resolution.
"""

from __future__ import annotations

import gzip
import json

from .inputs import DIGITS, SLIDER_DECIMALS

SOFTWARE_RENDER_SCALE = 0.5
"""The 3D view's resolution, as a fraction of the screen's, in a browser that draws WebGL in software."""
ESTOP_KEY = "Escape"
CLICKED_FIELD = "Clicked state"
"""The label of the editor's hidden text field the script writes a clicked state into (web/editor.py)."""

SCRIPT = (
    """<script>
(function () {
  var KEY = "ESTOP_KEY";
  // software WebGL: the 3D view at a lower resolution, unless the URL chooses one (before viser reads the URL)
  function softwareWebGL() {
    try {
      var gl = document.createElement("canvas").getContext("webgl");
      if (!gl) return false;
      var info = gl.getExtension("WEBGL_debug_renderer_info");
      var renderer = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER)).toLowerCase();
      var lose = gl.getExtension("WEBGL_lose_context");
      if (lose) lose.loseContext();
      return /swiftshader|llvmpipe|softpipe|software/.test(renderer);
    } catch (error) {
      return false;
    }
  }
  var query = new URLSearchParams(window.location.search);
  if (query.get("fixedDpr") === null && softwareWebGL()) {
    query.set("fixedDpr", String(SOFTWARE_RENDER_SCALE * (window.devicePixelRatio || 1)));
    var here = window.location;
    window.history.replaceState(window.history.state, "", here.pathname + "?" + query + here.hash);
    window.__asmSoftwareScale = SOFTWARE_RENDER_SCALE;
  }
  function estopButton() {
    var buttons = document.querySelectorAll("button");
    for (var i = 0; i < buttons.length; i++) {
      if (/^E-STOP/.test((buttons[i].textContent || "").trim())) return buttons[i];
    }
    return null;
  }
  function expandPanels() {
    var handles = document.querySelectorAll('[aria-label*="Expand"], [title*="Expand"]');
    for (var i = 0; i < handles.length; i++) handles[i].click();
  }
  window.addEventListener("keydown", function (event) {
    if (event.key !== KEY || event.repeat) return;
    var button = estopButton();
    if (button) { button.click(); return; }
    expandPanels();  // a folded panel holds the E-STOP: unfold it, then press
    setTimeout(function () { var again = estopButton(); if (again) again.click(); }, 50);
  }, true);
  function hideSettings() {
    var collapse = document.querySelectorAll('[aria-label="Collapse panel area"]');
    for (var j = 0; j < collapse.length; j++) collapse[j].style.display = "none";
    var icons = document.querySelectorAll("svg.tabler-icon-adjustments, svg.tabler-icon-arrow-back");
    for (var i = 0; i < icons.length; i++) {
      var action = icons[i].closest("button, .mantine-ActionIcon-root");
      if (action && action.style.display !== "none") action.style.display = "none";
    }
  }
  new MutationObserver(hideSettings).observe(document.documentElement, {childList: true, subtree: true});
  // number fields: what is typed stays in the field until it is committed (Enter, Tab, a step arrow, leaving it)
  var passing = false;
  var pending = new WeakSet();
  function isNumber(el) {
    return !!el && el.tagName === "INPUT" && el.classList.contains("mantine-NumberInput-input");
  }
  // a plain decimal only: the field's formatter dropped what it did not take ("0,1" became 1, "1e400" 1400, "2e-1"
  // -21) and an emptied field kept its old value; such text is not sent but marked, and said under the field
  var setValue = Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set;  // bypassing React
  var NUMBER = /^\\s*[+-]?(\\d+(\\.\\d*)?|\\.\\d+)\\s*$/;
  function withheld(el, said) {  // refused at a commit: the field emptied (its formatter, on the blur that follows,
    // would send its own reading of the text; an empty field sends nothing) and what was typed said under it
    setValue.call(el, "");
    el.asmTainted = false;
    refuse(el, said);
    return false;
  }
  function refuse(el, said) {
    el.setAttribute("aria-invalid", "true");
    el.style.outline = "2px solid #e03131";
    var note = el.asmNote;
    if (!note) {
      note = el.asmNote = document.createElement("div");
      note.setAttribute("data-asm-refused", "");
      note.style.cssText = "color:#e03131;font-size:0.75em;";
      var box = el.closest(".mantine-NumberInput-root");
      var row = box && sliderRange(el) ? box.parentElement.parentElement : null;  // a slider's: under it, as wide
      (row || box || el.parentElement).appendChild(note);
    }
    note.textContent = "⚠ " + said;
  }
  function accepted(el) {
    el.removeAttribute("aria-invalid");
    el.style.outline = "";
    if (el.asmNote) { el.asmNote.remove(); el.asmNote = null; }
  }
  function sliderRange(el) {  // [min, max, label] of the slider whose number box ``el`` is, else null
    var box = el.closest(".mantine-NumberInput-root");
    var thumb = box && box.parentElement && box.parentElement.querySelector('[role="slider"]');
    if (!thumb) return null;
    var low = Number(thumb.getAttribute("aria-valuemin")), high = Number(thumb.getAttribute("aria-valuemax"));
    var root = thumb.closest(".mantine-Slider-root");
    var label = root && root.id && document.querySelector('label[for="' + root.id + '"]');
    return isFinite(low) && isFinite(high) ? [low, high, label ? (label.textContent || "").trim() : ""] : null;
  }
  function commit(el) {  // false: refused (the event that asked for it must not reach the field's own handlers)
    if (!pending.has(el)) return true;
    var text = el.value;
    if (el.asmNote && !text.trim()) return false;  // refused, and still empty: nothing to send, the reason stays
    if (el.asmTainted)  // a key was refused since the field was last emptied: its text is not what was meant
      return withheld(el, "not sent: a key typed was not part of a number; type the number again");
    if (!NUMBER.test(text))  // kept pending: the next commit tries again
      return withheld(el, "not sent: " + JSON.stringify(text.slice(0, 40)) + " is not a number (digits, one " +
                      "point, a sign)");
    var range = sliderRange(el);  // a slider's box: out of its range, the field would clamp it without a word
    if (range && (Number(text) < range[0] || Number(text) > range[1]))
      return withheld(el, "not sent: " + text.trim() + " is out of range: " + (range[2] || "this slider") +
                      " goes from " + range[0] + " to " + range[1]);
    var decimals = /\\.(\\d*?)0*\\s*$/.exec(text);  // the field's formatter would round what is past its precision
    var takes = range ? SLIDER_DECIMALS[range[2]] : undefined;  // a slider's: what its step allows
    if (takes !== undefined && decimals && decimals[1].length > takes)
      return withheld(el, "not sent: " + text.trim() + (takes === 0 ? " is not a whole number: " + range[2] +
                      " takes whole numbers" : " has more decimal places than " + range[2] + " takes (" + takes +
                      ")") + " (the box would round it)");
    if (!range && decimals && decimals[1].length > DECIMALS)
      return withheld(el, "not sent: " + text.trim() + " has more than DECIMALS decimal places (the field would " +
                      "round it)");
    pending.delete(el);
    accepted(el);
    passing = true;
    try {  // as if the field were cleared, then the text pasted: the field's formatter takes it whole
      setValue.call(el, "");
      el.dispatchEvent(new Event("input", {bubbles: true}));
      setValue.call(el, text);
      el.setSelectionRange(text.length, text.length);
      el.dispatchEvent(new Event("input", {bubbles: true}));
    } finally { passing = false; }
    return true;
  }
  window.addEventListener("input", function (event) {
    if (passing || !isNumber(event.target)) return;
    event.stopImmediatePropagation();
    pending.add(event.target);
    if (event.target.value === "") event.target.asmTainted = false;
  }, true);
  window.addEventListener("keydown", function (event) {
    var el = event.target;
    if (!isNumber(el)) return;
    if (/^(Enter|Tab|ArrowUp|ArrowDown)$/.test(event.key) && !commit(el)) {
      event.stopImmediatePropagation();  // the field's formatter would send its own reading of the text
      return;
    }
    if (event.key.length !== 1 || event.ctrlKey || event.metaKey || event.altKey) return;
    if (el.selectionStart === 0 && el.selectionEnd === el.value.length) el.asmTainted = false;  // typed over all
    if (!/[0-9.+\\-]/.test(event.key)) {  // a key the formatter would drop without a word ("," or "e")
      event.preventDefault();
      event.stopImmediatePropagation();
      pending.add(el);
      el.asmTainted = true;  // what the field holds is not what was typed, until it is emptied or typed over
      refuse(el, JSON.stringify(event.key) + " is not part of a number here (digits, one point, a sign): not typed");
    }
  }, true);
  window.addEventListener("focusout", function (event) {
    if (isNumber(event.target) && !commit(event.target)) event.stopImmediatePropagation();  // its blur sends too
  }, true);
  // a click on a state (a row of the state grid, a cell of the states table) selects it: the page's hidden
  // "CLICKED" field is set to "automaton:index:count" (count: the same state clicked again is still news)
  var clicks = 0;
  var ROW = /^(\\S+) S(\\d+)(?: ⇥\\S+)? \\(°, s\\)$/;
  function clickedState(el) {
    var cell = el.closest && el.closest("[data-asm-state]");
    if (cell) return cell.getAttribute("data-asm-state");
    for (var up = el, i = 0; up && i < 8; up = up.parentElement, i++) {
      var label = up.querySelector && up.querySelector("label");
      var match = label && ROW.exec((label.textContent || "").trim());
      if (match && up.querySelectorAll("label").length === 1) return match[1] + ":" + (Number(match[2]) - 1);
    }
    return null;
  }
  function field(text) {
    var labels = document.querySelectorAll("label");
    for (var i = 0; i < labels.length; i++) {
      if ((labels[i].textContent || "").trim() !== text) continue;
      var row = labels[i].closest(".mantine-Flex-root");  // viser's text input: its label's "for" names nothing
      return row && row.querySelector("input");
    }
    return null;
  }
  window.addEventListener("click", function (event) {
    var state = clickedState(event.target);
    var input = state && field("CLICKED");
    if (!input) return;
    clicks += 1;
    setValue.call(input, state + ":" + clicks);
    input.dispatchEvent(new Event("input", {bubbles: true}));
  }, true);
  var hidden = null;
  function hideClicked() {
    if (hidden && hidden.isConnected) return;
    var input = field("CLICKED");
    var row = input && input.closest(".mantine-Flex-root");
    if (row && row.parentElement) { row.parentElement.style.display = "none"; hidden = input; }
  }
  new MutationObserver(hideClicked).observe(document.documentElement, {childList: true, subtree: true});
  // a double-click selects the whole number (the browser's word selection left out a minus sign)
  window.addEventListener("dblclick", function (event) {
    if (isNumber(event.target)) event.target.select();
  }, true);
  // ?maxFps=N: animation frames at most N a second (before the page's bundle runs, so every caller is capped)
  var asked = new URLSearchParams(window.location.search).get("maxFps");
  var maxFps = asked === null ? DEFAULT_MAX_FPS : Number(asked);
  if (maxFps >= 1 && maxFps < 60) {
    var nativeFrame = window.requestAnimationFrame.bind(window);
    var interval = 1000 / maxFps, due = 0, waiting = [], timer = null, ids = 0;
    var runFrame = function (time) {
      var run = waiting;
      waiting = [];
      for (var k = 0; k < run.length; k++) run[k][1](time);
    };
    var flush = function () {
      timer = null;
      due = performance.now() + interval;
      nativeFrame(runFrame);
    };
    window.requestAnimationFrame = function (callback) {
      ids += 1;
      waiting.push([ids, callback]);
      if (timer === null) timer = setTimeout(flush, Math.max(0, due - performance.now()));
      return ids;
    };
    window.cancelAnimationFrame = function (id) {
      waiting = waiting.filter(function (entry) { return entry[0] !== id; });
    };
    window.__asmMaxFps = maxFps;
  }
})();
</script>""".replace("ESTOP_KEY", ESTOP_KEY)
    .replace("CLICKED", CLICKED_FIELD)
    .replace("SOFTWARE_RENDER_SCALE", repr(SOFTWARE_RENDER_SCALE))
    .replace("SLIDER_DECIMALS", json.dumps(SLIDER_DECIMALS))
    .replace("DECIMALS", str(DIGITS))
)

STYLE = """<style>
button:has(> svg.tabler-icon-adjustments), .mantine-ActionIcon-root:has(svg.tabler-icon-adjustments),
[aria-label="Collapse panel area"] {
  display: none !important;
}
p, li {
  overflow-wrap: anywhere;
}
</style>"""


def inject(body: bytes, *, gzipped: bool, max_fps: float | None = None) -> bytes:
    """The page ``body`` (gzip-compressed when ``gzipped``) with the script and style in its head; ``max_fps``: the
    page's frame cap when its URL gives none (the studio's ``--max-fps``)."""
    html = gzip.decompress(body) if gzipped else body
    marker = b"</head>"
    at = html.find(marker)
    if at < 0:
        return body
    script = SCRIPT.replace("DEFAULT_MAX_FPS", "null" if max_fps is None else repr(float(max_fps)))
    html = html[:at] + (STYLE + script).encode("utf-8") + html[at:]
    return gzip.compress(html) if gzipped else html
