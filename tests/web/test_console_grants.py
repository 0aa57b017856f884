"""Control changing hands in the console, in a real browser (as test_console_commands): a
grant over another's lease asks the manager first and its holder is told, and a grant's
message says which boat and what the server did (a user nobody knows, a lease a grant
does not shorten). A world of its own (the module's), in file order: ana holds every
vehicle at the start."""

from __future__ import annotations

import re
from typing import Any

import pytest
from playwright.sync_api import expect

from tests.web import console_helpers as console
from tests.web.conftest import Shots, World

pytestmark = [pytest.mark.slow, pytest.mark.browser]


def test_control_given_over_its_holder_asks_first_and_the_holder_is_told(
    world: World, open_console: Any, shots: Shots
) -> None:
    """A grant to someone while another holds the vehicle ends the holder's lease: the
    manager is asked first (it happened silently), and the holder is told (nothing said)."""
    instance = world.instances["demo-usv-1"]
    holder, _ = open_console()
    console.log_in(holder, "ana")
    page, guard = open_console()
    console.log_in(page, "mia")
    world.as_user("ben", "POST", "/client/request_control", json={"instance_id": instance})
    page.click('[data-tab="control"]')
    card = page.locator('form.request[data-user="ben"][data-vehicle="demo-usv-1"]')
    title, text = page.locator("#confirm-title"), page.locator("#confirm-text")
    card.locator("button[type=submit]").click()
    expect(title).to_have_text("Give control of H2OmniX Alpha to ben?")
    asked = r"^ana holds H2OmniX Alpha until \d\d:\d\d:\d\d; give control to ben instead\? "
    expect(text).to_have_text(re.compile(asked))
    shots(page, "asked")
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert not [r for r in guard.requests if "/client/grant_control" in r]
    assert console.lease_of(world, instance)["holder"] == "ana"
    card.locator("button[type=submit]").click()
    ok = page.locator("#confirm-ok")
    expect(ok).to_be_enabled()
    ok.click()
    expect(page.locator('li.lease[data-vehicle="demo-usv-1"]')).to_contain_text("ben until")
    assert console.lease_of(world, instance)["holder"] == "ben"
    told = "control of H2OmniX Alpha passed to ben (granted by mia); it holds station"
    expect(holder.locator("#toasts")).to_contain_text(told)
    shots(holder, "holder-told")
    # the form that grants to anyone asks as well
    form = page.locator("details.grant")
    form.locator("summary").click()
    form.locator("select[name=vehicle]").select_option("demo-usv-2")
    form.locator("input[name=user]").fill("ben")
    form.locator("button[type=submit]").click()
    expect(title).to_have_text("Give control of H2OmniX Bravo to ben?")
    expect(text).to_have_text(re.compile(asked.replace("Alpha", "Bravo")))
    page.locator("#confirm-cancel").click()
    expect(page.locator("#confirm")).to_be_hidden()
    assert console.lease_of(world, world.instances["demo-usv-2"])["holder"] == "ana"
    world.fleet.grant(instance, "ana")


def test_a_grant_says_which_boat_and_what_the_server_did(
    world: World, open_console: Any, shots: Shots
) -> None:
    """The toast said "control granted to ben until ..." (which boat?); a user mistyped
    read "no such user: no such user"; a grant for less than the holder has left, which the
    server ignores (a grant never shortens a lease), read as a plain success."""
    world.fleet.grant(world.instances["demo-usv-3"], "ben")  # for 1 h
    world.fleet.call(
        "POST", "/client/revoke_control", json={"instance_id": world.instances["demo-usv-1"]}
    )
    page, _ = open_console()
    console.log_in(page, "mia")
    page.click('[data-tab="control"]')
    form = page.locator("details.grant")
    form.locator("summary").click()
    toasts = page.locator("#toasts")

    def grant(vehicle: str, user: str, duration_s: int) -> None:
        form.locator("select[name=vehicle]").select_option(vehicle)
        form.locator("input[name=user]").fill(user)
        form.locator("select[name=duration]").select_option(str(duration_s))
        form.locator("button[type=submit]").click()

    grant("demo-usv-1", "bne", 3600)  # a name nobody knows: questioned first, then sent
    expect(form.locator("#grant-user-check")).to_contain_text("did you mean ben?")
    form.locator("button[type=submit]").click()
    expect(toasts).to_contain_text("grant refused: cannot grant control to bne: no such user")
    assert "no such user: no such user" not in toasts.inner_text()
    grant("demo-usv-3", "ben", 300)
    kept = r"ben already holds H2OmniX Charlie until \d\d:\d\d:\d\d; a grant never shortens a lease"
    expect(toasts).to_contain_text(re.compile(kept))
    shots(page, "not-shortened")
    grant("demo-usv-3", "ben", 86400)
    expect(toasts).to_contain_text(re.compile(r"control of H2OmniX Charlie granted to ben until "))
