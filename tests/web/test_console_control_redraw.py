"""The Control panel drawn again, in a real browser: only when what it shows changes, and
never under a press (a button swapped under a finger did nothing). A world of its own
(the module's)."""

from __future__ import annotations

from typing import Any

from playwright.sync_api import expect

from tests.web.conftest import World
from tests.web.console_helpers import log_in, next_frames


def ana_s_lease_in_mia_s_control_panel(world: World, open_console: Any) -> tuple[Any, Any]:
    """ana holds demo-usv-1; mia (its manager) has the Control panel open at its lease,
    Revoke on it: the page and the lease's item."""
    world.fleet.grant(world.instances["demo-usv-1"], "ana")
    page, _ = open_console()
    log_in(page, "mia")
    page.click('[data-tab="control"]')
    lease = page.locator('li.lease[data-vehicle="demo-usv-1"]')
    expect(lease.locator("button", has_text="Revoke")).to_be_visible()
    return page, lease


def test_a_press_on_the_control_panel_outlasts_its_redraw(world: World, open_console: Any) -> None:
    """A Grant tapped on a phone did nothing now and then: the panel was drawn again (on
    any vehicle's news) between the press and its end, and the button pressed was gone."""
    page, _ = ana_s_lease_in_mia_s_control_panel(world, open_console)
    x, y = page.evaluate(  # where the button is (the same place in every redraw)
        """() => {
            const b = [...document.querySelectorAll('li.lease[data-vehicle="demo-usv-1"] button')]
                .find((e) => e.textContent.includes("Revoke"));
            b.scrollIntoView({ block: "center" });
            const r = b.getBoundingClientRect();
            return [r.x + r.width / 2, r.y + r.height / 2];
        }"""
    )
    page.mouse.move(x, y)
    page.mouse.down()
    page.evaluate(  # news the panel shows (the boat's presence) while the button is held down
        "fleetConsole.fleet.applyFleet({vehicles: [{vehicle_id: 'demo-usv-1', presence: 'stale'}]})"
    )
    next_frames(page)
    page.mouse.up()
    expect(page.locator("#confirm-title")).to_contain_text("Revoke")
    page.click("#confirm-cancel")


def test_the_control_panel_is_drawn_again_only_when_what_it_shows_changes(
    world: World, open_console: Any
) -> None:
    """The panel was drawn again on every vehicle's news (each position, another boat's
    link), its buttons swapped under the pointer several times a second for nothing."""
    page, lease = ana_s_lease_in_mia_s_control_panel(world, open_console)
    # Two minutes on: the lease's countdown ("in 60 min") turns, kept current in place by
    # the clock's tick, which is no reason to draw the panel again (it was, once a minute;
    # seen failing make test under load).
    page.evaluate("() => { const real = Date.now.bind(Date); Date.now = () => real() + 120_000; }")
    # What the panel shows, its countdowns aside.
    shown = """() => {
        const probe = document.getElementById("control-pane").cloneNode(true);
        for (const el of probe.querySelectorAll("small.until")) el.textContent = "";
        return probe.innerHTML;
    }"""
    # A loaded machine may make a boat stale meanwhile, or log a safety event: shown, so
    # drawn again; then try again.
    for _ in range(3):
        page.evaluate(
            f"""() => {{
                window.revokeButton = [...document.querySelectorAll(
                    'li.lease[data-vehicle="demo-usv-1"] button')].find(
                    (b) => b.textContent.includes("Revoke"));
                const v = fleetConsole.fleet.vehicles.get("demo-usv-1");
                window.positionBefore = v.view.position.ts;
                window.shownBefore = ({shown})();
            }}"""
        )
        other_link = "{vehicles: [{vehicle_id: 'demo-usv-2', link_rtt_ms: 42}]}"
        # News the panel does not show: another boat's link, this one's position.
        page.evaluate(f"fleetConsole.fleet.applyFleet({other_link})")
        page.wait_for_function(  # a new position from the boat itself (its agent runs at 1 Hz)
            "() => fleetConsole.fleet.vehicles.get('demo-usv-1').view.position.ts"
            " !== window.positionBefore",
            timeout=15_000,
        )
        next_frames(page)  # the redraws asked have run
        if page.evaluate("window.revokeButton.isConnected"):
            break
        assert page.evaluate(f"({shown})() !== window.shownBefore"), "drawn again for nothing"
    else:
        raise AssertionError("what the panel shows changed at every try")
    page.evaluate(  # news it shows: the boat's presence
        "fleetConsole.fleet.applyFleet({vehicles: [{vehicle_id: 'demo-usv-1', presence: 'stale'}]})"
    )
    next_frames(page)
    assert not page.evaluate("window.revokeButton.isConnected")
    expect(lease).to_contain_text("stale")
