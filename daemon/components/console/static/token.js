// The token for this tab: kept in sessionStorage, asked for once, its refusal shown as such.

const KEY = "arbiterd.token";
const ASKED = "arbiterd.token-asked";

export class TokenBox {
  constructor({ dialog, form, input, why, cancel, onChange }) {
    Object.assign(this, { dialog, form, input, why, onChange });
    form.addEventListener("submit", (event) => {
      event.preventDefault();
      this.dialog.close();
      this.set(this.input.value.trim());
    });
    cancel.addEventListener("click", () => this.dialog.close());
  }

  get() { return sessionStorage.getItem(KEY) || ""; }

  set(token) {
    if (token) sessionStorage.setItem(KEY, token);
    else sessionStorage.removeItem(KEY);
    this.onChange(token);
  }

  // Opens the prompt; `automatic` prompts happen once per tab, asked-for ones always.
  ask(reason, { refused = false, automatic = false } = {}) {
    if (automatic && sessionStorage.getItem(ASKED)) return;
    sessionStorage.setItem(ASKED, "1");
    this.why.textContent = reason;
    this.why.dataset.kind = refused ? "refused" : "needed";
    this.input.value = "";
    if (!this.dialog.open) this.dialog.showModal();
    this.input.focus();
  }
}
