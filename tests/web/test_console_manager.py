"""What the console offers a field manager, in a real browser (as test_console_commands):
she takes control of the vehicles she manages (she was offered "Request control", which
only asks herself), an operator still asks for it, and the grant form picks the user from
those who asked and those known rather than taking any name typed. A world of its own
(the module's), in file order: ana holds every vehicle at the start."""

from __future__ import annotations

from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web.conftest import Shots, World
from tests.web.console_helpers import log_in, marker

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def holder_of(world: World, vehicle_id: str) -> str | None:
    body = {"instance_id": world.instances[vehicle_id]}
    control = world.fleet.call("POST", "/client/connect_instance", json=body)["instance"]["control"]
    return control["holder"] if control else None


def grant_calls(guard: Any) -> list[str]:
    return [r for r in guard.requests if r.startswith("POST ") and "/client/grant_control" in r]


def test_a_manager_takes_control_where_an_operator_requests_it(
    world: World, open_console: Any, shots: Shots
) -> None:
    """mia manages every vehicle: the vehicle panel, the lease list and a refused command
    offered her "Request control" (a request only she would answer); her own lease offered
    Revoke beside Release."""
    page, guard = open_console()
    log_in(page, "mia")
    marker(page, "demo-usv-2").click()
    line = page.locator("#vehicle-pane .control-line")
    expect(line).to_contain_text("ana holds control until")
    expect(line.locator("button", has_text="Take control")).to_be_visible()
    expect(line.locator("button", has_text="Request")).to_have_count(0)
    page.click('[data-tab="control"]')
    lease = page.locator('li.lease[data-vehicle="demo-usv-2"]')
    expect(lease.locator("button", has_text="Take control")).to_be_visible()
    expect(page.locator("#control-pane button", has_text="Request")).to_have_count(0)
    shots(page, "offered-take")
    # ana holds it: taking it ends her lease, so it asks first
    lease.locator("button", has_text="Take control").click()
    expect(page.locator("#confirm-title")).to_have_text("Take control of H2OmniX Bravo from ana?")
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert grant_calls(guard) == [] and holder_of(world, "demo-usv-2") == "ana"
    lease.locator("button", has_text="Take control").click()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(lease).to_contain_text("you until")
    expect(lease.locator("button", has_text="Release")).to_be_visible()
    # her own lease: Release, not also "Revoke" ("Revoke mia's control of Bravo?", asked of
    # mia), as the vehicle panel offers it
    expect(lease.locator("button", has_text="Revoke")).to_have_count(0)
    assert holder_of(world, "demo-usv-2") == "mia"
    shots(page, "taken")
    # a command refused for want of control offers her to take it, not to ask
    world.fleet.call(
        "POST", "/client/revoke_control", json={"instance_id": world.instances["demo-usv-3"]}
    )
    marker(page, "demo-usv-3").click()
    page.click("#hold")
    refused = page.locator("#toasts .toast.error", has_text="you do not hold control")
    expect(refused.locator("button", has_text="Take control")).to_be_visible()
    refused.locator("button", has_text="Take control").click()  # nobody holds it: no question
    expect(page.locator("#vehicle-pane .control-line")).to_contain_text("you hold control until")
    assert holder_of(world, "demo-usv-3") == "mia"
    # an operator is still offered to ask
    other, _ = open_console()
    log_in(other, "ben")
    marker(other, "demo-usv-2").click()
    theirs = other.locator("#vehicle-pane .control-line")
    expect(theirs).to_contain_text("mia holds control until")
    expect(theirs.locator("button", has_text="Request control")).to_be_visible()
    expect(theirs.locator("button", has_text="Take control")).to_have_count(0)
    other.click('[data-tab="control"]')
    expect(other.locator("#control-pane button", has_text="Take control")).to_have_count(0)
    for vehicle in ("demo-usv-2", "demo-usv-3"):
        world.fleet.grant(world.instances[vehicle], "ana")


def test_the_grant_form_picks_who_asked_and_questions_an_unknown_name(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The user was typed by hand: a typo went to the server. Now the requesters (and the
    people known to hold control) are offered; a name nobody knows is questioned, with the
    likely one, and nothing is sent until it is confirmed (then the server's word shows)."""
    instance = world.instances["demo-usv-1"]
    world.as_user("ben", "POST", "/client/request_control", json={"instance_id": instance})
    world.fleet.call("POST", "/client/revoke_control", json={"instance_id": instance})
    page, guard = open_console()
    log_in(page, "mia")
    page.click('[data-tab="control"]')
    form = page.locator("details.grant")
    form.locator("summary").click()
    options = form.locator("datalist#grant-users option")
    expect(options.first).to_have_attribute("value", "ben")  # who asked first
    expect(options.first).to_have_attribute("label", "ben: asks for H2OmniX Alpha")
    assert "ana" in options.evaluate_all("os => os.map(o => o.value)")  # she held them
    user = form.locator("input[name=user]")
    expect(user).to_have_attribute("list", "grant-users")
    form.locator("select[name=vehicle]").select_option("demo-usv-1")
    user.fill("bne")
    form.locator("button[type=submit]").click()
    said = form.locator("#grant-user-check")
    expect(said).to_be_visible()
    expect(said).to_contain_text("“bne” is not someone who asked for control or held it here")
    expect(said).to_contain_text("did you mean ben?")
    expect(user).to_have_attribute("aria-invalid", "true")
    assert grant_calls(guard) == []  # nothing sent
    shots(page, "unknown-questioned")
    # sent on purpose: the server's refusal shows in the form, not only in a passing toast
    expect(form.locator("button[type=submit]")).to_have_text("Grant to bne anyway")
    form.locator("button[type=submit]").click()
    expect(said).to_contain_text("cannot grant control to bne: no such user")
    assert len(grant_calls(guard)) == 1
    assert holder_of(world, "demo-usv-1") is None
    # the one who asked, picked: granted
    user.fill("ben")
    expect(said).to_have_count(0)
    form.locator("button[type=submit]").click()
    expect(page.locator('li.lease[data-vehicle="demo-usv-1"]')).to_contain_text("ben until")
    assert holder_of(world, "demo-usv-1") == "ben"
    shots(page, "granted-from-list")
    world.fleet.grant(instance, "ana")
