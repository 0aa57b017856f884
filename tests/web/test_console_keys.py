"""What a field tester found with a keyboard and in the panels, in a real browser (as
test_console_input): the fleet table's tick boxes and the vehicle panel's buttons keep the
keyboard's focus while samples come in (each sample drew them anew: the focus fell to the
page within a second), a map marker reached with Tab is selected by Enter or Space, "plan
round obstacles" says in words why it is off for several boats (and is unticked then),
the vehicle panel's battery reads as the table's, and the replay's window is brought up to
the moment its tab opens, but not from under the answer read for it (after Back to live the
old window's summary and Export stayed under a window moved on). A world of its own (the
module's): ana holds every vehicle."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web import console_helpers as console
from tests.web.conftest import Shots, World
from tests.web.console_helpers import replay_up

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def samples_drawn(page: Any, vehicle_id: str, n: int = 3) -> None:
    """Until ``n`` more samples of the vehicle have come in (2 a second) and been drawn."""
    page.evaluate(
        """([id, n]) => new Promise((done) => {
            let seen = 0;
            const fleet = fleetConsole.fleet;
            const on = (e) => {
                if (e.detail.id !== id || e.detail.what !== "position" || ++seen < n) return;
                fleet.removeEventListener("change", on);
                requestAnimationFrame(() => requestAnimationFrame(done));
            };
            fleet.addEventListener("change", on);
        })""",
        [vehicle_id, n],
    )


def focused(page: Any) -> str:
    """What has the keyboard's focus: the tag, and its label or text."""
    return str(
        page.evaluate(
            """() => { const el = document.activeElement;
                return `${el.tagName} ${el.getAttribute("aria-label") || el.textContent}`; }"""
        )
    )


def test_a_tick_box_keeps_the_focus_while_samples_come_in(
    world: World, open_console: Any, shots: Shots
) -> None:
    """Tab to a tick box, wait a second, press Space: nothing was selected (the box had
    been drawn anew with the next sample, the focus on the page's body)."""
    page, _ = open_console()
    console.log_in(page, "ana")
    rows = page.locator("#fleet-table tbody tr")
    rows.locator('[aria-label="select demo-usv-1"]').focus()
    page.keyboard.press("Tab")  # to the next row's tick box
    assert focused(page) == "INPUT select demo-usv-2"
    samples_drawn(page, "demo-usv-2")
    assert focused(page) == "INPUT select demo-usv-2"
    page.keyboard.press("Space")
    expect(page.locator("#selection")).to_have_text("1 selected: H2OmniX Bravo")
    expect(page.locator('#fleet-table tr[data-vehicle="demo-usv-2"]')).to_have_class(
        re.compile(r"\bselected\b")
    )
    page.keyboard.press("Tab")
    samples_drawn(page, "demo-usv-3")
    page.keyboard.press("Space")
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Bravo, H2OmniX Charlie")
    shots(page, "ticked-by-keyboard")


def test_a_marker_reached_with_tab_is_selected_by_enter_or_space(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A marker is reached with Tab (role=button), but Enter and Space did nothing."""
    page, _ = open_console()
    console.log_in(page, "ana")
    console.marker(page, "demo-usv-1").focus()
    page.keyboard.press("Enter")  # selected alone, its panel open, as a click does
    expect(page.locator("#selection")).to_have_text("1 selected: H2OmniX Alpha")
    expect(page.locator('.tabs [data-tab="vehicle"]')).to_have_attribute("aria-selected", "true")
    expect(page.locator("#vehicle-pane h2")).to_contain_text("H2OmniX Alpha")
    console.marker(page, "demo-usv-3").focus()
    page.keyboard.press(" ")
    expect(page.locator("#selection")).to_have_text("1 selected: H2OmniX Charlie")
    expect(console.marker(page, "demo-usv-3")).to_have_class(re.compile(r"\bselected\b"))
    shots(page, "marker-by-keyboard")


def test_the_vehicle_panel_s_buttons_keep_the_focus_while_samples_come_in(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The panel's buttons (Release, refresh, ...) were drawn anew with every sample: one
    focused with Tab lost the focus before Enter was pressed."""
    page, _ = open_console()
    console.log_in(page, "ana")
    console.marker(page, "demo-usv-3").click()
    release = page.locator("#vehicle-pane button", has_text="Release")
    release.focus()
    samples_drawn(page, "demo-usv-3")
    assert focused(page) == "BUTTON Release"
    page.keyboard.press("Enter")
    expect(page.locator("#confirm-title")).to_have_text("Release your control of H2OmniX Charlie?")
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    refresh = page.locator("#vehicle-pane button", has_text="refresh")
    refresh.focus()
    samples_drawn(page, "demo-usv-3")
    assert focused(page) == "BUTTON refresh"
    shots(page, "panel-button-still-focused")


def test_plan_round_obstacles_says_why_it_is_off_for_several_boats(
    world: World, open_console: Any, shots: Shots
) -> None:
    """With several boats selected the box was greyed out but still ticked, and why only in
    a tooltip (a phone shows none). Now it is unticked and says why beside it, and ticked
    again as the person left it when one boat is selected again."""
    page, _ = open_console()
    console.log_in(page, "ana")
    plan, why = page.locator("#path-plan"), page.locator("#path-plan-why")
    console.marker(page, "demo-usv-1").click()
    page.click('#actions [data-tool="path"]')
    expect(plan).to_be_enabled()
    expect(plan).to_be_checked()
    expect(why).to_be_hidden()
    console.marker(page, "demo-usv-2").click(modifiers=["Shift"])
    expect(page.locator("#selection")).to_have_text("2 selected: H2OmniX Alpha, H2OmniX Bravo")
    expect(plan).to_be_disabled()
    expect(plan).not_to_be_checked()
    expect(why).to_be_visible()
    expect(why).to_contain_text("off for several boats")
    expect(why).to_contain_text("goes as drawn")
    shots(page, "several-boats")
    console.marker(page, "demo-usv-2").click()  # one boat again
    expect(page.locator("#selection")).to_have_text("1 selected: H2OmniX Bravo")
    expect(plan).to_be_enabled()
    expect(plan).to_be_checked()
    expect(why).to_be_hidden()
    plan.uncheck()  # the person's choice, kept across several boats and back
    console.marker(page, "demo-usv-3").click(modifiers=["Shift"])
    expect(plan).to_be_disabled()
    expect(plan).not_to_be_checked()
    console.marker(page, "demo-usv-3").click()
    expect(plan).to_be_enabled()
    expect(plan).not_to_be_checked()
    page.click("#path-cancel")


def test_the_panel_rounds_the_battery_as_the_table(
    world: World, open_console: Any, shots: Shots
) -> None:
    """At 99.56 % the fleet table said 99 % and the vehicle panel 100 %. A sample of
    99.56 % is handed to the page as the telemetry topic would (dated a minute ahead, so
    that the vehicle's own samples do not replace it while the test reads)."""
    page, _ = open_console()
    console.log_in(page, "ana")
    console.marker(page, "demo-usv-2").click()
    page.evaluate(
        """(id) => {
            const v = fleetConsole.fleet.vehicles.get(id);
            const ts = new Date(Date.now() + 60000).toISOString();
            fleetConsole.fleet.applyTelemetry(id, { ...v.view.position, ts, battery_pct: 99.56 });
        }""",
        "demo-usv-2",
    )
    cell = page.locator('#fleet-table tr[data-vehicle="demo-usv-2"] td').nth(3)
    panel = page.locator("#vehicle-pane dl.readings").locator(
        "xpath=dt[.='battery']/following-sibling::dd[1]"
    )
    expect(cell).to_have_text("99 %")
    expect(panel).to_have_text("99 %")
    shots(page, "battery-99")


def test_the_replay_window_is_up_to_date_when_its_tab_opens(
    world: World, open_console: Any, shots: Shots
) -> None:
    """At 16:09 the replay still offered a window ending at 16:03 (set when the page
    loaded). The browser's clock is moved on (Playwright's clock) between loading the page
    and opening the tab: the window (15 min, or the shortcut pressed) ends when the tab
    opens; one typed stays as typed."""
    page, _ = open_console()
    page.clock.install()
    console.log_in(page, "ana")
    frm, to = page.locator("#replay-from"), page.locator("#replay-to")

    def window() -> tuple[float, float, float]:
        got = page.evaluate(
            """() => [document.getElementById("replay-from").value,
                      document.getElementById("replay-to").value, Date.now()]
                .map((x) => (typeof x === "number" ? x
                    : new Date(x.replace(" ", "T")).getTime()))"""
        )
        return got[0], got[1], got[2]

    replay_up(page)
    page.clock.fast_forward("07:00")  # seven minutes on
    page.click('[data-tab="replay"]')
    start, end, now = window()
    assert now - 5000 < end <= now, (end, now)  # up to now, not to when the page loaded
    assert end - start == 15 * 60000
    page.click('#replay-form [data-minutes="60"]')
    page.click('[data-tab="fleet"]')
    page.clock.fast_forward("03:00")
    page.click('[data-tab="replay"]')
    start, end, now = window()
    assert now - 5000 < end <= now and end - start == 3600000  # the last hour, up to now

    typed = console.local_times(page, 4, 3)
    frm.fill(typed[0])
    to.fill(typed[1])
    page.click('[data-tab="fleet"]')
    page.clock.fast_forward("02:00")
    page.click('[data-tab="replay"]')
    expect(frm).to_have_value(typed[0])
    expect(to).to_have_value(typed[1])
    shots(page, "typed-window-kept")


def test_a_refused_window_leaves_no_earlier_answer_under_the_form(
    world: World, open_console: Any, shots: Shots
) -> None:
    """After "the window must start before it ends" the earlier "Nothing was recorded…"
    stayed under the form, as if it answered the window refused."""
    page, _ = open_console()
    console.log_in(page, "ana")
    replay_up(page)
    page.click('[data-tab="replay"]')
    frm, to = page.locator("#replay-from"), page.locator("#replay-to")
    # an hour that ended three hours before now (before the server started)
    typed = console.local_times(page, 4, 3)
    frm.fill(typed[0])
    to.fill(typed[1])
    info = page.locator("#replay-info")
    page.click("#replay-load")
    expect(info).to_contain_text("Nothing was recorded for these vehicles")
    to.fill(typed[0])  # the window ends where it starts
    frm.fill(typed[1])
    page.click("#replay-load")
    expect(info).to_have_text("the window must start before it ends: nothing read")
    expect(info).not_to_contain_text("Nothing was recorded")
    shots(page, "refused-window")


def test_a_replay_s_answer_stays_with_the_window_it_read(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A replay of the last 5 minutes, Back to live, and a minute later the Replay tab
    opened again: its window had moved on, but the summary, the events and the Export
    buttons were still the old window's, and GPX saved the old window. The form stays on
    the window read while its answer is shown; changing the form takes the answer away."""
    page, _ = open_console()
    page.clock.install()
    console.log_in(page, "ana")
    replay_up(page)
    frm, to = page.locator("#replay-from"), page.locator("#replay-to")
    info, export = page.locator("#replay-info"), page.locator("#replay-export")
    events = page.locator("#replay-events")

    def load_5_minutes() -> tuple[str, str]:
        page.click('#replay-form [data-minutes="5"]')
        page.click("#replay-load")
        expect(page.locator("#replay-bar")).to_be_visible()
        window = frm.input_value(), to.input_value()
        expect(info).to_contain_text(f"{window[0]} ")
        expect(info).to_contain_text(f" to {window[1]} ")
        return window

    def answer_gone() -> None:
        expect(info).to_have_text("")
        expect(export).to_be_hidden()
        expect(events).to_be_hidden()

    page.click('[data-tab="replay"]')
    read = load_5_minutes()
    expect(events.locator("li").first).to_be_visible()
    page.click("#replay-exit")
    page.clock.fast_forward("01:00")
    page.click('[data-tab="fleet"]')
    page.click('[data-tab="replay"]')
    shots(page, "replay-tab-again")
    # what is shown under the form is the answer to the window in it
    assert (frm.input_value(), to.input_value()) == read
    expect(info).to_contain_text(f"{read[0]} ")
    expect(info).to_contain_text(f" to {read[1]} ")
    expect(export).to_be_visible()
    with page.expect_download() as got:
        page.click('#replay-export button[data-format="gpx"]')
    utc = page.evaluate(
        """(t) => new Date(t.replace(" ", "T")).toISOString().slice(0, 19).replace(/:/g, "")""",
        read[0],
    )
    assert got.value.suggested_filename.endswith(f"-{utc}Z.gpx"), got.value.suggested_filename

    # a shortcut pressed: the window moves on, and the old answer goes with it
    page.click('#replay-form [data-minutes="15"]')
    assert frm.input_value() != read[0]
    answer_gone()
    shots(page, "window-changed")
    page.click("#replay-load")  # the answer to the window now in the form
    expect(info).to_contain_text(f"{frm.input_value()} ")
    expect(export).to_be_visible()
    expect(events).to_be_visible()
    page.click("#replay-exit")
    # a time typed, or a vehicle unticked, the same
    load_5_minutes()
    page.click("#replay-exit")
    frm.fill(console.local_times(page, 0.2)[0])
    answer_gone()
    load_5_minutes()
    page.locator('#replay-vehicles input[value="demo-usv-2"]').uncheck()
    answer_gone()
