"""Every status a solver or a verdict gives a plan, as one enum.

`Status` is a `StrEnum`: a member equals, hashes, prints and is written to JSON as its text, so
solution files and comparisons with the text are what they were. IPOPT's statuses are CasADi's
words for IPOPT's return codes (`Status.of` reads them); the others are ours: projected Newton's
and the interior point's ends, and the verdicts the limits, the certificate and the methods give.
The baseline and the gradient variant are not solvers: their status is a sentence about their run
("not optimised", "completed 100 iterations"), kept as text.
"""

from __future__ import annotations

from enum import StrEnum


class Status(StrEnum):
    """A plan's status: a solver's end or a verdict on its plan."""

    # IPOPT's (CasADi's `return_status`), and ours where they mean the same
    SOLVE_SUCCEEDED = "Solve_Succeeded"
    SOLVED_TO_ACCEPTABLE_LEVEL = "Solved_To_Acceptable_Level"
    FEASIBLE_POINT_FOUND = "Feasible_Point_Found"
    INFEASIBLE_PROBLEM_DETECTED = "Infeasible_Problem_Detected"
    MAXIMUM_ITERATIONS_EXCEEDED = "Maximum_Iterations_Exceeded"
    RESTORATION_FAILED = "Restoration_Failed"
    ERROR_IN_STEP_COMPUTATION = "Error_In_Step_Computation"
    SEARCH_DIRECTION_BECOMES_TOO_SMALL = "Search_Direction_Becomes_Too_Small"
    DIVERGING_ITERATES = "Diverging_Iterates"
    USER_REQUESTED_STOP = "User_Requested_Stop"
    MAXIMUM_CPUTIME_EXCEEDED = "Maximum_CpuTime_Exceeded"
    MAXIMUM_WALLTIME_EXCEEDED = "Maximum_WallTime_Exceeded"
    NOT_ENOUGH_DEGREES_OF_FREEDOM = "Not_Enough_Degrees_Of_Freedom"
    INVALID_PROBLEM_DEFINITION = "Invalid_Problem_Definition"
    INVALID_OPTION = "Invalid_Option"
    INVALID_NUMBER_DETECTED = "Invalid_Number_Detected"
    UNRECOVERABLE_EXCEPTION = "Unrecoverable_Exception"
    NONIPOPT_EXCEPTION_THROWN = "NonIpopt_Exception_Thrown"
    INSUFFICIENT_MEMORY = "Insufficient_Memory"
    INTERNAL_ERROR = "Internal_Error"
    UNKNOWN = "Unknown"  # CasADi's when IPOPT gave none

    # projected Newton's and the interior point's own ends
    STALLED = "Stalled"  # the step no longer lowers the objective, not yet converged
    LINE_SEARCH_FAILED = "Line_Search_Failed"
    SINGULAR_HESSIAN = "Singular_Hessian"
    INFEASIBLE_START = "Infeasible_Start"  # the start is outside a row the method must keep
    DEPTH_BOUND_VIOLATED = "Depth_Bound_Violated"  # Newton's plan went below min_depth
    TERMINAL_POSE_NOT_MET = "Terminal_Pose_Not_Met"

    # verdicts on a plan
    INITIAL_GUESS_KEPT = "Initial_Guess_Kept"  # no converged point was better than the start
    MOTION_LIMITS_VIOLATED = "Motion_Limits_Violated"  # the played curve breaks an enforced limit
    NOT_CERTIFIED = "Not_Certified"  # a claimed success the certificate does not confirm
    GOAL_UNREACHABLE = "Goal_Unreachable"  # a re-plan's goal outside the robot's reach
    DURATION_LENGTHENED = "Duration_Lengthened"  # a baseline in more steps than the horizon
    CONFIDENCE_NOT_REACHED = "Confidence_Not_Reached"  # no horizon reached the asked confidence

    @classmethod
    def of(cls, text: str) -> Status:
        """The member whose text is `text` (e.g. a backend's `return_status`); a ValueError naming
        the known ones otherwise (a new backend status is added here, never passed through)."""
        try:
            return cls(text)
        except ValueError:
            raise ValueError(f"unknown solver status {text!r}; known: "
                             f"{', '.join(s.value for s in cls)}") from None
