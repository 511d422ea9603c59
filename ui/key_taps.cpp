#include "key_taps.h"

#include <GLFW/glfw3.h>

#include <algorithm>
#include <vector>

namespace refocus {

namespace {
GLFWkeyfun g_previous = nullptr;
std::vector<int> g_taps;

void on_key(GLFWwindow* window, int key, int scancode, int action, int mods) {
    if (action == GLFW_PRESS) g_taps.push_back(key);
    if (g_previous) g_previous(window, key, scancode, action, mods);
}
}  // namespace

void install_key_taps(GLFWwindow* window) {
    g_previous = glfwSetKeyCallback(window, on_key);
}

bool key_tapped(int key) {
    return std::find(g_taps.begin(), g_taps.end(), key) != g_taps.end();
}

void clear_key_taps() {
    g_taps.clear();
}

}  // namespace refocus
