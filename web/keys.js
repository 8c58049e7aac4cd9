// Keyboard shortcuts. Space is STOP everywhere except while typing in a text field (Escape works
// there too); listened for in the capture phase so no focused button can swallow it.

const TYPING = new Set(["text", "password", "search", "number", "email", "url"]);

function typing(target) {
  return (target.tagName === "INPUT" && TYPING.has(target.type)) || target.tagName === "TEXTAREA"
    || target.isContentEditable;
}

export function installKeys(h) {
  window.addEventListener("keydown", (ev) => {
    if (ev.key === "Escape") {
      ev.preventDefault();
      h.stop(false);
      return;
    }
    if (typing(ev.target) || ev.ctrlKey || ev.metaKey || ev.altKey) return;
    if (ev.code === "Space") {
      ev.preventDefault(); // no page scroll, no "click" of the focused button
      if (!ev.repeat) h.stop(ev.shiftKey);
      return;
    }
    if (ev.repeat) return;
    const key = ev.key.toLowerCase();
    const act = {
      s: h.start, r: h.resume, e: h.end, c: h.toggleControl,
      j: () => { flip("jog-kind"); h.toggleKind(); },
      t: () => flip("frame"),
      "+": () => speed(5, h), "=": () => speed(5, h), "-": () => speed(-5, h),
    }[key];
    if (act) {
      ev.preventDefault();
      act();
    }
  }, true);
  // A focused button activates on Space *release*: swallow that too.
  window.addEventListener("keyup", (ev) => {
    if (ev.code === "Space" && !typing(ev.target)) ev.preventDefault();
  }, true);
}

function flip(name) {
  const radios = [...document.querySelectorAll(`input[name="${name}"]`)];
  const i = radios.findIndex((r) => r.checked);
  radios[(i + 1) % radios.length].checked = true;
}

function speed(delta, h) {
  const input = document.getElementById("speed");
  input.value = String(Math.min(100, Math.max(1, Number(input.value) + delta)));
  h.showSpeed();
}
