// Drawing a panel again without taking the person's place away: the fleet table and the
// vehicle panel are drawn again on every telemetry sample, and a tick box or a button
// replaced by a new one lost the keyboard's focus (to the page's body) within a second.
// ``patchChildren`` puts the new drawing in place of the old one but keeps every element
// that is the same one (its tag, and its key or its class), changing only what differs:
// a focused control stays the very element it was, with its focus.

/** What makes an element the same one across drawings: its tag, and its key (data-key,
 * data-sends, data-command, data-vehicle) or, without one, its class. An element kept
 * keeps its listeners: every element whose listener depends on more than its place in
 * the panel carries a key (a button that sends: ``sends(key)``; a fleet row: its vehicle). */
function keyOf(el) {
  const d = el.dataset;
  const key = d.key ?? d.sends ?? d.command ?? d.vehicle;
  return key === undefined ? `${el.tagName}.${el.className}` : `${el.tagName}#${key}`;
}

function sameOne(a, b) {
  if (a.nodeType !== b.nodeType) return false;
  if (a.nodeType !== Node.ELEMENT_NODE) return true; // text: its words are updated
  return keyOf(a) === keyOf(b);
}

/** ``old`` made to read as ``now`` (the same one): its attributes, checked state and
 * children; ``old`` is returned, kept. */
function patch(old, now) {
  if (old.nodeType !== Node.ELEMENT_NODE) {
    if (old.data !== now.data) old.data = now.data;
    return old;
  }
  for (const { name, value } of now.attributes) {
    if (old.getAttribute(name) !== value) old.setAttribute(name, value);
  }
  for (const { name } of [...old.attributes]) {
    if (!now.hasAttribute(name)) old.removeAttribute(name);
  }
  if (old.tagName === "INPUT" && old.checked !== now.checked) old.checked = now.checked;
  place(old, [...now.childNodes]);
  return old;
}

function place(parent, nodes) {
  const old = [...parent.childNodes];
  const kept = new Set();
  let from = 0;
  const out = nodes.map((n) => {
    for (let i = from; i < old.length; i += 1) {
      if (old[i] === n || sameOne(old[i], n)) {
        from = i + 1;
        kept.add(old[i]);
        return old[i] === n ? n : patch(old[i], n); // itself: as it is (a row not changed)
      }
    }
    return n;
  });
  for (const o of old) if (!kept.has(o)) o.remove();
  // the nodes kept are in their order already: only new ones are inserted, none moved
  // (a node moved would lose its focus)
  out.forEach((n, i) => {
    const at = parent.childNodes[i];
    if (at !== n) parent.insertBefore(n, at || null);
  });
}

/** The focused control's key, when it is in ``parent``: restored on the new one when the
 * old one could not be kept (a lease renewed: its line drawn anew). */
function focusKey(parent) {
  const el = document.activeElement;
  if (!el || el === document.body || !parent.contains(el)) return null;
  return el.dataset.key ?? el.dataset.sends ?? null;
}

/**
 * Put ``nodes`` (null and false left out) in ``parent`` in place of its children, keeping
 * each old element that is the same one (see ``keyOf``) and changing only what differs.
 * The focused control stays focused: kept, or, if it is gone, its successor (the same
 * key) focused instead.
 */
export function patchChildren(parent, nodes) {
  const key = focusKey(parent);
  const focused = document.activeElement;
  place(parent, nodes.flat().filter((n) => n !== null && n !== undefined && n !== false)
    .map((n) => (n instanceof Node ? n : document.createTextNode(String(n)))));
  if (key === null || focused.isConnected) return;
  const next = [...parent.querySelectorAll("[data-key], [data-sends]")]
    .find((el) => (el.dataset.key ?? el.dataset.sends) === key);
  if (next && !next.disabled) next.focus({ preventScroll: true });
}
