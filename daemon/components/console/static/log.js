// Log tail: the daemon's /rosout lines (INFO and up), newest last, the last MAX_LINES kept.

const MAX_LINES = 200;
const LEVELS = { 10: "DEBUG", 20: "INFO", 30: "WARN", 40: "ERROR", 50: "FATAL" };

const two = (n) => String(n).padStart(2, "0");

export function logTime(stamp) {
  const d = new Date((stamp?.sec ?? 0) * 1000);
  return `${two(d.getHours())}:${two(d.getMinutes())}:${two(d.getSeconds())}`;
}

export class LogTail {
  constructor(list) {
    this.list = list;
  }

  // One rcl_interfaces/msg/Log message.
  add(msg) {
    const follow = this.list.scrollTop + this.list.clientHeight >= this.list.scrollHeight - 4;
    const level = LEVELS[msg.level] || String(msg.level);
    const li = document.createElement("li");
    li.dataset.level = level;
    const tag = document.createElement("span");
    tag.className = "level";
    tag.textContent = level;
    li.append(`${logTime(msg.stamp)} `, tag, ` ${msg.name}: ${msg.msg}`);
    this.list.append(li);
    while (this.list.children.length > MAX_LINES) this.list.firstElementChild.remove();
    if (follow) this.list.scrollTop = this.list.scrollHeight;
  }
}
