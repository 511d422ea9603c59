#pragma once
// A fit's tuning as typed, named settings ("fast.lr_atlas", "radius.floor_max", ...). Each
// setting is a field of an options struct (FitOptions, FitSetupOptions, FastModelOptions,
// PaperModelOptions, PerframeOptions, StackCocOptions) whose initialiser is its one default.
// A Settings object holds the values the user changed (project.json "fit.settings", or
// `refocus fit --set name=value`), validated when set; apply_settings() copies them into the
// struct at the place that builds it.
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

namespace refocus {

struct FitOptions;
struct FitSetupOptions;
struct FastModelOptions;
struct PaperModelOptions;
struct PerframeOptions;
struct StackCocOptions;

// One setting as `refocus fit --list-settings` prints it.
struct SettingInfo {
    std::string name;   // group.field
    std::string type;   // number | integer | bool | one of: a|b
    std::string def;    // the default, as text
    std::string range;  // "[lo, hi]" or the choices
    std::string help;
};

// Every setting, grouped and in a stable order.
const std::vector<SettingInfo>& all_settings();
// The table `--list-settings` prints.
std::string settings_table();

class Settings {
  public:
    // Validates `name` and `value` (type and range) and stores the value in canonical form.
    // Throws Error naming the setting and its valid range, or listing the valid names.
    void set(const std::string& name, const std::string& value);
    // "name=value" as typed after --set.
    void set_assignment(const std::string& assignment);
    // From project.json's fit.settings object (`where` names it in errors).
    void set_json(const nlohmann::json& obj, const std::string& where);
    nlohmann::json to_json() const;

    bool has(const std::string& name) const { return m_values.count(name) != 0; }
    const std::string& value(const std::string& name) const { return m_values.at(name); }
    const std::map<std::string, std::string>& values() const { return m_values; }
    bool empty() const { return m_values.empty(); }
    // "/name=value" for each set value whose name starts with `prefix`: for keys of caches
    // whose content those settings shape (empty when all are at their defaults).
    std::string key(const std::string& prefix) const;

  private:
    std::map<std::string, std::string> m_values;
};

void apply_settings(const Settings& s, FitOptions& o);
void apply_settings(const Settings& s, FitSetupOptions& o);
void apply_settings(const Settings& s, FastModelOptions& o);
void apply_settings(const Settings& s, PaperModelOptions& o);
void apply_settings(const Settings& s, PerframeOptions& o);
void apply_settings(const Settings& s, StackCocOptions& o);

}  // namespace refocus
