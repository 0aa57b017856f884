// What is wrong with a vehicle now (VehicleView.alarms), as the fleet table and the
// vehicle panel say it: each alarm's words and since when (in this browser's time).

import { alarmLabel } from "./fleet.js";
import { clock, h } from "./ui.js";

/** An alarm in words, and since when when the server knows it:
 * "battery low: 15 % (alarm below 20 %) since 10:02:11". */
export function alarmText(a) {
  return a.since ? `${a.message} since ${clock(a.since)}` : a.message;
}

/** A vehicle's alarms as red badges, each saying what is wrong, and since when, in its
 * title. */
export function alarmBadges(view) {
  return (view.alarms || []).map((a) => h(`span.alarm.a-${a.kind}`, { title: alarmText(a) },
    alarmLabel(a.kind)));
}

/** The list at the top of the vehicle panel (null when nothing is wrong). */
export function alarmList(view) {
  const alarms = view.alarms || [];
  return alarms.length
    ? h("ul.alarm-list", { role: "alert" }, ...alarms.map((a) => h("li", {}, alarmText(a))))
    : null;
}
