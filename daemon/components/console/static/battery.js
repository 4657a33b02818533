// The battery gauge of the top bar: /battery_state's charge, coloured by [battery]'s thresholds.

// thresholds until GET /api/battery tells the robot's own ([battery] low, very_low, critical)
const DEFAULTS = { low: 0.2, very_low: 0.15, critical: 0.12 };
const STATUS = ["unknown", "charging", "discharging", "not charging", "full"];

export function levelOf(percentage, thresholds, charging) {
  if (charging) return "ok";
  if (percentage < thresholds.critical) return "critical";
  if (percentage < thresholds.very_low) return "very_low";
  if (percentage < thresholds.low) return "low";
  return "ok";
}

export class BatteryGauge {
  constructor(pill, onChange) {
    this.pill = pill;
    this.onChange = onChange;
    this.thresholds = DEFAULTS;
    this.warning = "";
  }

  setThresholds(thresholds) {
    if (thresholds) this.thresholds = { ...DEFAULTS, ...thresholds };
  }

  // one sensor_msgs/msg/BatteryState
  update(msg) {
    const pct = Math.round(msg.percentage * 100);
    const status = STATUS[msg.power_supply_status] || "unknown";
    const charging = msg.power_supply_status === 1 || msg.power_supply_status === 4;
    const level = levelOf(msg.percentage, this.thresholds, charging);
    this.pill.hidden = false;
    this.pill.textContent = `battery ${pct} %${charging ? " ⚡" : ""}`;
    this.pill.title = `${msg.voltage.toFixed(2)} V, ${msg.current.toFixed(2)} A, ${status}`;
    this.pill.dataset.state = { ok: "ok", low: "degraded", very_low: "error",
      critical: "error" }[level];
    const warning = {
      ok: "",
      low: `Battery low: ${pct} %. The robot should go home to charge.`,
      very_low: `Battery very low: ${pct} %. New goals, missions and fetches are refused until it charges.`,
      critical: `Battery critical: ${pct} %. The motors are stopped and the recording closed.`,
    }[level];
    if (warning !== this.warning) {
      this.warning = warning;
      this.onChange(warning);
    }
  }
}
